//! The subcommands that only print: `demo` (the engine on the built-in sample) and `bench`
//! (speed beside OpenCV SGBM and Open3D). Their errors are `anyhow` (printed by `main.rs`, never
//! handled); the library under them returns typed errors. `eval` stays a library module: its
//! metrics serve the tests too.

pub mod bench;
pub mod demo;

/// The one line `main.rs` prints for a failed command: the error and its causes, each cause
/// left out where the text before it already says it (the library's errors put their cause in
/// their own message, so `anyhow`'s `{:#}` printed it twice).
pub fn error_line(error: &anyhow::Error) -> String {
    let mut line = String::new();
    for cause in error.chain() {
        let text = cause.to_string();
        if line.contains(&text) {
            continue;
        }
        if !line.is_empty() {
            line.push_str(": ");
        }
        line.push_str(&text);
    }
    line
}

#[cfg(test)]
mod tests {
    /// A cause that its error's message already holds is said once; one it does not hold is
    /// added after it (anyhow's context).
    #[test]
    fn error_line_says_each_cause_once() {
        let io = std::io::Error::new(std::io::ErrorKind::NotFound, "no such file");
        let bag = crate::bag::BagError::Io {
            path: "in.mcap".into(),
            source: io,
        };
        let error = anyhow::Error::from(bag);
        assert_eq!(format!("{error:#}"), "in.mcap: no such file: no such file");
        assert_eq!(super::error_line(&error), "in.mcap: no such file");
        let error = error.context("reading the input");
        assert_eq!(
            super::error_line(&error),
            "reading the input: in.mcap: no such file"
        );
    }
}
