//! What the CPU offers the kernels: its model and the vector instruction sets detected at run
//! time. Benchmarks name them beside every timing, since the same binary runs different
//! kernels on different CPUs (gemm and our host kernels dispatch at run time).

/// The CPU's model name, as the operating system reports it (`/proc/cpuinfo` on Linux).
pub fn cpu_model() -> String {
    std::fs::read_to_string("/proc/cpuinfo")
        .ok()
        .and_then(|text| {
            text.lines()
                .find(|line| line.starts_with("model name"))
                .and_then(|line| line.split_once(':'))
                .map(|(_, name)| name.trim().to_string())
        })
        .unwrap_or_else(|| std::env::consts::ARCH.to_string())
}

/// The vector instruction sets this CPU has, of those the kernels can use.
pub fn simd_features() -> Vec<&'static str> {
    let mut found = Vec::new();
    #[cfg(target_arch = "x86_64")]
    {
        macro_rules! detect {
            ($($feature:tt),*) => {
                $(if std::is_x86_feature_detected!($feature) {
                    found.push($feature);
                })*
            };
        }
        detect!(
            "sse4.2",
            "avx",
            "avx2",
            "fma",
            "avx512f",
            "avx512bw",
            "avx512cd",
            "avx512dq",
            "avx512vl",
            "avx512vnni",
            "avx512bf16",
            "avx512fp16"
        );
    }
    #[cfg(target_arch = "aarch64")]
    if std::arch::is_aarch64_feature_detected!("neon") {
        found.push("neon");
    }
    found
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn the_features_are_those_the_cpu_reports() {
        let features = simd_features();
        #[cfg(target_arch = "x86_64")]
        {
            assert_eq!(
                features.contains(&"avx2"),
                std::is_x86_feature_detected!("avx2")
            );
            assert_eq!(
                features.contains(&"avx512f"),
                std::is_x86_feature_detected!("avx512f")
            );
            // Every x86-64 CPU since 2009 has SSE4.2: a list without it was not detected.
            assert!(features.contains(&"sse4.2"), "{features:?}");
        }
        assert!(!cpu_model().is_empty());
    }
}
