//! The embedded font, registered with plotters once per process.

use std::sync::Once;

use plotters::style::FontStyle;

/// The family name every chart asks for.
pub const FAMILY: &str = "sans-serif";

static DEJAVU_SANS: &[u8] = include_bytes!("../fonts/DejaVuSans-subset.ttf");

/// Registers the embedded font; every drawing function calls it first.
pub fn ensure_registered() {
    static REGISTER: Once = Once::new();
    REGISTER.call_once(|| {
        // The bytes are a valid TrueType file checked in beside this crate (a test draws text
        // with them), so a failure here would be a broken checkout; text is then not drawn,
        // and the chart is still written.
        let _ = plotters::style::register_font(FAMILY, FontStyle::Normal, DEJAVU_SANS);
    });
}
