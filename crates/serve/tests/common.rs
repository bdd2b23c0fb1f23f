//! A server on a free loopback port with the reference model, and a plain HTTP/1.1 client
//! (raw requests, so tests can send any Host, Origin or Content-Type).

#![allow(dead_code)]

use std::io::{Read, Write};
use std::net::{SocketAddr, TcpStream};
use std::path::PathBuf;

use burn::prelude::Device;
use diffkfc_serve::{Engine, Running, ServeOptions};

pub fn model_dir() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("../../models/tiny-synth")
}

/// The editor's server with `queue` waiting places, or None (after a notice) when the text
/// encoder is not installed; DIFFKFC_REQUIRE_FIXTURES=1 (CI) makes that a failure.
pub fn server(queue: usize) -> Option<Running> {
    let opts =
        ServeOptions { host: "127.0.0.1".parse().unwrap(), port: 0, allow_hosts: vec![], queue };
    match diffkfc_serve::start(&opts, || Engine::load(&model_dir(), &Device::flex())) {
        Ok(r) => Some(r),
        Err(e) if e.to_string().contains("text encoder") => {
            if std::env::var("DIFFKFC_REQUIRE_FIXTURES").is_ok_and(|v| v == "1") {
                panic!("text encoder required: {e}");
            }
            eprintln!("SKIPPED: {e}");
            None
        }
        Err(e) => panic!("{e}"),
    }
}

/// A response: status, headers (lower-case names) and body.
pub struct Reply {
    pub status: u16,
    pub headers: Vec<(String, String)>,
    pub body: Vec<u8>,
}

impl Reply {
    pub fn json(&self) -> serde_json::Value {
        serde_json::from_slice(&self.body)
            .unwrap_or_else(|e| panic!("not JSON ({e}): {}", String::from_utf8_lossy(&self.body)))
    }
    pub fn error(&self) -> String {
        self.json()["error"].as_str().unwrap_or_else(|| panic!("no error field")).to_string()
    }
}

/// Send one request; `headers` replace the defaults (Host: the server's address,
/// Content-Type: application/json on a body).
pub fn http(
    addr: SocketAddr,
    method: &str,
    path: &str,
    headers: &[(&str, &str)],
    body: &[u8],
) -> Reply {
    let mut s = TcpStream::connect(addr).unwrap();
    s.set_read_timeout(Some(std::time::Duration::from_secs(120))).unwrap();
    let has = |n: &str| headers.iter().any(|(k, _)| k.eq_ignore_ascii_case(n));
    let mut head = format!(
        "{method} {path} HTTP/1.1\r\nConnection: close\r\nContent-Length: {}\r\n",
        body.len()
    );
    if !has("host") {
        head += &format!("Host: {addr}\r\n");
    }
    if !has("content-type") && !body.is_empty() {
        head += "Content-Type: application/json\r\n";
    }
    for (k, v) in headers {
        head += &format!("{k}: {v}\r\n");
    }
    head += "\r\n";
    // The server may answer and close before reading a refused body: ignore write errors.
    let _ = s.write_all(head.as_bytes()).and_then(|_| s.write_all(body));
    let mut raw = Vec::new();
    let _ = s.read_to_end(&mut raw);
    parse(&raw)
}

fn parse(raw: &[u8]) -> Reply {
    let split = raw.windows(4).position(|w| w == b"\r\n\r\n").expect("a complete response");
    let head = String::from_utf8_lossy(&raw[..split]).to_string();
    let mut lines = head.lines();
    let status: u16 = lines.next().unwrap().split(' ').nth(1).unwrap().parse().unwrap();
    let headers: Vec<(String, String)> = lines
        .filter_map(|l| l.split_once(':'))
        .map(|(k, v)| (k.trim().to_ascii_lowercase(), v.trim().to_string()))
        .collect();
    let mut body = raw[split + 4..].to_vec();
    if headers.iter().any(|(k, v)| k == "transfer-encoding" && v.contains("chunked")) {
        body = dechunk(&body);
    }
    Reply { status, headers, body }
}

fn dechunk(mut b: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    loop {
        let eol = b.windows(2).position(|w| w == b"\r\n").unwrap();
        let n = usize::from_str_radix(String::from_utf8_lossy(&b[..eol]).trim(), 16).unwrap();
        if n == 0 {
            return out;
        }
        out.extend_from_slice(&b[eol + 2..eol + 2 + n]);
        b = &b[eol + 4 + n..];
    }
}

/// POST JSON.
pub fn post(addr: SocketAddr, path: &str, body: &serde_json::Value) -> Reply {
    http(addr, "POST", path, &[], body.to_string().as_bytes())
}
