//! Library errors and panics → the `panoman.Error` classes (`panoman/_errors.py`).

use super::*;

/// A library error or a caught panic, carried out of a GIL-free section.
pub(crate) enum Failure {
    Lib(panoman::Error),
    Panic(String),
}

/// The `panoman._errors` class of a library error (by its [`panoman::ErrorKind`]).
pub(crate) fn error_class(e: &panoman::Error) -> &'static str {
    kind_class(e.kind())
}

/// The `panoman._errors` class of an error kind.
pub(crate) fn kind_class(k: panoman::ErrorKind) -> &'static str {
    use panoman::ErrorKind as K;
    match k {
        K::File => "FileError",
        K::Format => "FormatError",
        K::Invalid => "InvalidError",
        K::Numerical => "NumericalError",
        _ => "Error",
    }
}

/// The error and its causes on one line, skipping causes whose text the line already holds
/// (the CLI's `one_line`: the messages are the same as `panoman … ` prints after `error: `).
pub(crate) fn one_line(e: &(dyn std::error::Error + 'static)) -> String {
    let mut msg = String::new();
    let mut cur: Option<&(dyn std::error::Error + 'static)> = Some(e);
    while let Some(c) = cur {
        let text = c.to_string().replace('\n', " ");
        if !msg.contains(&text) {
            if !msg.is_empty() {
                msg.push_str(": ");
            }
            msg.push_str(&text);
        }
        cur = c.source();
    }
    msg
}

/// Raises `panoman.<class>(message)`.
pub(crate) fn raise(py: Python<'_>, class: &str, message: String) -> PyErr {
    let made = py
        .import("panoman._errors")
        .and_then(|m| m.getattr(class))
        .and_then(|c| c.call1((message.clone(),)));
    match made {
        Ok(exc) => PyErr::from_value(exc),
        Err(e) => e,
    }
}

/// `panoman.InvalidError` (a `ValueError`) with `message`.
pub(crate) fn invalid(py: Python<'_>, message: impl Into<String>) -> PyErr {
    raise(py, "InvalidError", message.into())
}

pub(crate) fn lib_err(py: Python<'_>, e: panoman::Error) -> PyErr {
    raise(py, error_class(&e), one_line(&e))
}

pub(crate) fn failure(py: Python<'_>, f: Failure) -> PyErr {
    match f {
        Failure::Lib(e) => lib_err(py, e),
        Failure::Panic(m) => raise(py, "InternalError", format!("internal error: {m}")),
    }
}

pub(crate) fn panic_text(p: Box<dyn std::any::Any + Send>) -> String {
    p.downcast_ref::<&str>()
        .map(|s| s.to_string())
        .or_else(|| p.downcast_ref::<String>().cloned())
        .unwrap_or_else(|| "panic".into())
}

/// Runs a library call with the GIL released, catching panics.
pub(crate) fn run<T: Send>(
    py: Python<'_>,
    f: impl FnOnce() -> panoman::Result<T> + Send,
) -> PyResult<T> {
    let out = py.detach(|| match catch_unwind(AssertUnwindSafe(f)) {
        Ok(Ok(v)) => Ok(v),
        Ok(Err(e)) => Err(Failure::Lib(e)),
        Err(p) => Err(Failure::Panic(panic_text(p))),
    });
    out.map_err(|f| failure(py, f))
}
