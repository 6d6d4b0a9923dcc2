//! The allocator option `keep_freed_memory` sets is mimalloc's purge delay: the index we name
//! is the option that `MIMALLOC_PURGE_DELAY` controls.

use std::process::Command;

const PROBE: &str = "the_purge_delay_option_is_the_one_its_environment_variable_sets";

#[test]
fn the_purge_delay_option_is_the_one_its_environment_variable_sets() {
    if std::env::var("MIMALLOC_PURGE_DELAY").as_deref() == Ok("1234") {
        // The child: mimalloc read the variable into the option we name.
        assert_eq!(bevworld_device::purge_delay_ms(), 1234);
        bevworld_device::keep_freed_memory();
        assert_eq!(bevworld_device::purge_delay_ms(), -1);
        return;
    }
    let exe = std::env::current_exe().expect("test binary");
    let status = Command::new(exe)
        .args(["--exact", PROBE, "--test-threads", "1"])
        .env("MIMALLOC_PURGE_DELAY", "1234")
        .status()
        .expect("run the probe");
    assert!(status.success(), "the probe failed: {status}");
}
