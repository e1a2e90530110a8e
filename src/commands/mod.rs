//! The command-line subcommands. Each takes its parsed arguments and returns an anyhow error
//! whose one-line rendering is what the user sees.

pub mod animate;
pub mod audio;
pub mod codec;
pub mod lipsync;
pub mod net;

/// The one line a user sees for an error: its chain joined by ": ", leaving out a cause whose
/// text is already in the line (library errors name their `io::Error` in their own message and
/// also give it as their source, which would print the OS error twice).
pub fn error_line(error: &anyhow::Error) -> String {
    let mut line = String::new();
    for cause in error.chain() {
        let text = cause.to_string();
        if text.is_empty() || line.contains(&text) {
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
    use super::*;

    #[test]
    fn an_os_error_named_by_its_wrapper_is_printed_once() {
        let e = crate::input::read(
            std::path::Path::new("/nonexistent/lipcall.wav"),
            crate::input::MAX_INPUT_BYTES,
        )
        .unwrap_err();
        let e = anyhow::Error::new(e).context("loading the head");
        let line = error_line(&e);
        assert_eq!(line.matches("os error 2").count(), 1, "{line}");
        assert!(line.starts_with("loading the head: cannot read"), "{line}");
    }
}
