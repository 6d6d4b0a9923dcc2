//! Typed, named ports. Validation compares `PortType`s so a mismatch is caught before any
//! thread starts; a node kind declares each port once, as a `Port<T>` constant, and uses that
//! constant for its spec and for every read and send, so that a name is never written twice
//! and a payload of another type does not compile.

use std::any::{Any, TypeId};
use std::marker::PhantomData;

/// A port's name and the payload type it carries.
pub struct Port<T> {
    pub name: &'static str,
    payload: PhantomData<fn() -> T>,
}

impl<T> Port<T> {
    pub const fn new(name: &'static str) -> Self {
        Self {
            name,
            payload: PhantomData,
        }
    }
}

impl<T: Any + Send + Sync> Port<T> {
    /// The port as a kind declares it: a required input, or an output.
    pub fn spec(&self) -> PortSpec {
        PortSpec::new::<T>(self.name)
    }

    /// The port as an input that may be left unconnected.
    pub fn optional(&self) -> PortSpec {
        PortSpec::optional::<T>(self.name)
    }
}

impl<T> Clone for Port<T> {
    fn clone(&self) -> Self {
        *self
    }
}
impl<T> Copy for Port<T> {}

impl<T> std::fmt::Debug for Port<T> {
    fn fmt(&self, f: &mut std::fmt::Formatter<'_>) -> std::fmt::Result {
        write!(f, "Port({})", self.name)
    }
}

/// The Rust type a port carries, with a readable name for diagnostics.
#[derive(Clone, Copy, Debug)]
pub struct PortType {
    name: &'static str,
    id: TypeId,
}

impl PortType {
    pub fn of<T: Any + Send + Sync>() -> Self {
        Self {
            name: short_type_name::<T>(),
            id: TypeId::of::<T>(),
        }
    }

    pub fn name(&self) -> &'static str {
        self.name
    }
}

impl PartialEq for PortType {
    fn eq(&self, other: &Self) -> bool {
        self.id == other.id
    }
}
impl Eq for PortType {}

/// One input or output of a node kind.
#[derive(Clone, Debug)]
pub struct PortSpec {
    pub name: &'static str,
    pub ty: PortType,
    /// An input that must be connected; ignored for outputs.
    pub required: bool,
}

impl PortSpec {
    /// A required input, or an output.
    pub fn new<T: Any + Send + Sync>(name: &'static str) -> Self {
        Self {
            name,
            ty: PortType::of::<T>(),
            required: true,
        }
    }

    /// An input that may be left unconnected.
    pub fn optional<T: Any + Send + Sync>(name: &'static str) -> Self {
        Self {
            name,
            ty: PortType::of::<T>(),
            required: false,
        }
    }
}

/// `std::any::type_name` without module paths: `alloc::sync::Arc<bevworld_types::Frame>` becomes
/// `Arc<Frame>`.
pub fn short_type_name<T: ?Sized>() -> &'static str {
    let full = std::any::type_name::<T>();
    // Leak once per distinct type; there are only a handful of port types in a process.
    use std::collections::HashMap;
    use std::sync::{Mutex, OnceLock};
    static CACHE: OnceLock<Mutex<HashMap<&'static str, &'static str>>> = OnceLock::new();
    let cache = CACHE.get_or_init(|| Mutex::new(HashMap::new()));
    let mut guard = match cache.lock() {
        Ok(guard) => guard,
        Err(poisoned) => poisoned.into_inner(),
    };
    guard
        .entry(full)
        .or_insert_with(|| Box::leak(strip_paths(full).into_boxed_str()))
}

fn strip_paths(full: &str) -> String {
    let mut out = String::with_capacity(full.len());
    let mut segment = String::new();
    for ch in full.chars() {
        if ch.is_alphanumeric() || ch == '_' || ch == ':' {
            segment.push(ch);
        } else {
            out.push_str(segment.rsplit("::").next().unwrap_or(""));
            segment.clear();
            out.push(ch);
        }
    }
    out.push_str(segment.rsplit("::").next().unwrap_or(""));
    out
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn strips_module_paths_inside_generics() {
        assert_eq!(strip_paths("alloc::sync::Arc<a::b::Frame>"), "Arc<Frame>");
        assert_eq!(strip_paths("(u8, std::string::String)"), "(u8, String)");
    }

    #[test]
    fn port_types_compare_by_type_not_name() {
        assert_eq!(PortType::of::<u32>(), PortType::of::<u32>());
        assert_ne!(PortType::of::<u32>(), PortType::of::<i32>());
    }
}
