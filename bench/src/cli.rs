//! The benchmark binaries' small command lines: a flag's value, and a failure printed as one
//! line with exit status 1.

/// The value after `name` on the command line, if given.
pub fn arg(name: &str) -> Option<String> {
    let args: Vec<String> = std::env::args().collect();
    args.iter()
        .position(|a| a == name)
        .and_then(|i| args.get(i + 1).cloned())
}

/// Prints `message` and exits with status 1.
pub fn fail(message: String) -> ! {
    eprintln!("{message}");
    std::process::exit(1);
}
