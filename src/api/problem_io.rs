//! Problem documents for the requests hyper refuses itself. hyper's HTTP/1
//! server answers a request it cannot parse before any handler runs: a URI
//! over 65 534 bytes gets `414`, a head over its read buffer `431`, a
//! malformed request line or header `400`, each with an empty body, and the
//! connection is closed after it. hyper offers no hook for these answers, so
//! the connection's byte stream is wrapped ([`ProblemIo`]): such an answer
//! is recognised as it is written (one of those statuses with
//! `content-length: 0`: every answer of a handler with these statuses is a
//! problem document, never empty) and replaced by the same status as an
//! RFC 9457 problem document. Decision: docs/decisions/0041-hard-problem-for-hyper-refusals.md.

use super::problem::Problem;
use axum::http::StatusCode;
use std::io;
use std::pin::Pin;
use std::task::{ready, Context, Poll};
use tokio::io::{AsyncRead, AsyncWrite, ReadBuf};

/// The problem document hyper's own answer with `status` stands for.
fn problem_for(status: u16) -> Option<Problem> {
    Some(match status {
        414 => Problem::new(
            StatusCode::URI_TOO_LONG,
            "uri-too-long",
            "URI too long",
            "the request's URI (path and query) is longer than the 65534 bytes the server reads; send large parameters in a POST body",
        ),
        431 => Problem::new(
            StatusCode::REQUEST_HEADER_FIELDS_TOO_LARGE,
            "headers-too-large",
            "Request header fields too large",
            "the request line and headers do not fit the server's read buffer (about 400 KB)",
        ),
        400 => Problem::bad_request(
            "the request line or a header is not valid HTTP/1.1 and could not be parsed",
        ),
        _ => return None,
    })
}

/// The status of hyper's own empty answer at the start of `buf`, if it is one.
fn hyper_refusal(buf: &[u8]) -> Option<u16> {
    // cheap first: bodies and other answers are not scanned
    if !buf.starts_with(b"HTTP/1.1 4") || buf.len() > 1024 {
        return None;
    }
    let head_end = buf.windows(4).position(|w| w == b"\r\n\r\n")?;
    let head = std::str::from_utf8(&buf[..head_end]).ok()?;
    let mut lines = head.split("\r\n");
    let status: u16 = lines
        .next()?
        .strip_prefix("HTTP/1.1 ")?
        .get(..3)?
        .parse()
        .ok()?;
    if !matches!(status, 400 | 414 | 431) || buf.len() != head_end + 4 {
        return None;
    }
    let empty = lines.any(|l| {
        l.split_once(':').is_some_and(|(k, v)| {
            k.trim().eq_ignore_ascii_case("content-length") && v.trim() == "0"
        })
    });
    empty.then_some(status)
}

/// The whole HTTP/1.1 answer carrying `p` (the connection closes after it).
fn problem_response(p: &Problem) -> Vec<u8> {
    let body = p.body().to_string();
    format!(
        "HTTP/1.1 {} {}\r\ncontent-type: application/problem+json\r\ncontent-length: {}\r\nconnection: close\r\n\r\n{body}",
        p.status.as_u16(),
        p.status.canonical_reason().unwrap_or(""),
        body.len()
    )
    .into_bytes()
}

/// A connection whose hyper-made refusals are rewritten into problem documents.
pub struct ProblemIo<S> {
    inner: S,
    /// A replacement being written: its bytes, how many are out, and the
    /// length of hyper's write it stands for.
    replacing: Option<(Vec<u8>, usize, usize)>,
    /// The replacement is out: hyper's further bytes are dropped.
    replaced: bool,
}

impl<S> ProblemIo<S> {
    pub fn new(inner: S) -> ProblemIo<S> {
        ProblemIo {
            inner,
            replacing: None,
            replaced: false,
        }
    }
}

impl<S: AsyncRead + Unpin> AsyncRead for ProblemIo<S> {
    fn poll_read(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &mut ReadBuf<'_>,
    ) -> Poll<io::Result<()>> {
        Pin::new(&mut self.inner).poll_read(cx, buf)
    }
}

impl<S: AsyncWrite + Unpin> AsyncWrite for ProblemIo<S> {
    fn poll_write(
        mut self: Pin<&mut Self>,
        cx: &mut Context<'_>,
        buf: &[u8],
    ) -> Poll<io::Result<usize>> {
        let this = &mut *self;
        if this.replaced {
            return Poll::Ready(Ok(buf.len()));
        }
        if this.replacing.is_none() {
            match hyper_refusal(buf).and_then(problem_for) {
                Some(p) => this.replacing = Some((problem_response(&p), 0, buf.len())),
                None => return Pin::new(&mut this.inner).poll_write(cx, buf),
            }
        }
        let (bytes, sent, claimed) = this.replacing.as_mut().expect("set above");
        while *sent < bytes.len() {
            let n = ready!(Pin::new(&mut this.inner).poll_write(cx, &bytes[*sent..]))?;
            if n == 0 {
                return Poll::Ready(Err(io::ErrorKind::WriteZero.into()));
            }
            *sent += n;
        }
        let claimed = *claimed;
        this.replacing = None;
        this.replaced = true;
        Poll::Ready(Ok(claimed))
    }

    fn poll_flush(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.inner).poll_flush(cx)
    }

    fn poll_shutdown(mut self: Pin<&mut Self>, cx: &mut Context<'_>) -> Poll<io::Result<()>> {
        Pin::new(&mut self.inner).poll_shutdown(cx)
    }

    // Not vectored: hyper then writes each answer's head as one buffer,
    // which is what `hyper_refusal` recognises.
    fn is_write_vectored(&self) -> bool {
        false
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    #[test]
    fn only_hyper_s_empty_refusals_are_recognised() {
        let h = b"HTTP/1.1 414 URI Too Long\r\ncontent-length: 0\r\ndate: Thu, 26 Nov 2026 20:00:00 GMT\r\n\r\n";
        assert_eq!(hyper_refusal(h), Some(414));
        let h = b"HTTP/1.1 431 Request Header Fields Too Large\r\ncontent-length: 0\r\n\r\n";
        assert_eq!(hyper_refusal(h), Some(431));
        // a handler's answer with a body is left alone
        let h = b"HTTP/1.1 400 Bad Request\r\ncontent-type: application/problem+json\r\ncontent-length: 0\r\n\r\n{}";
        assert_eq!(hyper_refusal(h), None);
        let h = b"HTTP/1.1 400 Bad Request\r\ncontent-length: 57\r\n\r\n";
        assert_eq!(hyper_refusal(h), None);
        let h = b"HTTP/1.1 200 OK\r\ncontent-length: 0\r\n\r\n";
        assert_eq!(hyper_refusal(h), None);
        let r = problem_response(&problem_for(414).unwrap());
        let text = String::from_utf8(r).unwrap();
        assert!(text.starts_with("HTTP/1.1 414 URI Too Long\r\n"), "{text}");
        let body: serde_json::Value =
            serde_json::from_str(text.split("\r\n\r\n").nth(1).unwrap()).unwrap();
        assert_eq!(body["status"], 414);
        assert_eq!(body["type"], "/problems/uri-too-long");
    }
}
