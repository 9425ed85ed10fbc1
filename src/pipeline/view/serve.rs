//! A static file server on the loopback interface, for the page `lumiprobe view`
//! writes (browsers run JavaScript modules only from `http://` pages). GET and
//! HEAD of files inside one folder; nothing else.

use crate::error::{Error, Result};
use std::io::{BufRead, BufReader, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::{Component, Path, PathBuf};
use std::time::Duration;

/// Longest request head read (request line and headers).
const MAX_HEAD_BYTES: usize = 16 << 10;

/// A server bound to `127.0.0.1`, not yet serving.
pub struct Server {
    listener: TcpListener,
    root: PathBuf,
}

impl Server {
    /// The address to open in a browser.
    pub fn url(&self) -> Result<String> {
        let addr = self
            .listener
            .local_addr()
            .map_err(|e| Error::Internal(format!("the server's address: {e}")))?;
        Ok(format!("http://{addr}/"))
    }

    /// Serves requests one after another until the process ends.
    pub fn run(self) -> Result<()> {
        for stream in self.listener.incoming() {
            // A client that hangs up or sends garbage costs its own request only.
            match stream {
                Ok(s) => {
                    let _ = handle(s, &self.root);
                }
                // Out of file descriptors and the like: wait instead of spinning.
                Err(_) => std::thread::sleep(Duration::from_millis(50)),
            }
        }
        Ok(())
    }
}

/// Binds a server for the files under `root` on `127.0.0.1:port` (0: any free
/// port).
pub fn serve(root: &Path, port: u16) -> Result<Server> {
    let root = root.canonicalize().map_err(|e| Error::io(root, e))?;
    let listener = TcpListener::bind(("127.0.0.1", port)).map_err(|e| {
        Error::Invalid(format!(
            "cannot listen on 127.0.0.1:{port} ({e}); choose another --port (0: any free one)"
        ))
    })?;
    Ok(Server { listener, root })
}

/// The content type of a file served by its extension.
fn content_type(path: &Path) -> &'static str {
    match path.extension().and_then(|e| e.to_str()).unwrap_or("") {
        "html" => "text/html; charset=utf-8",
        "js" | "mjs" => "text/javascript; charset=utf-8",
        "json" | "gltf" => "application/json",
        "png" => "image/png",
        "jpg" | "jpeg" => "image/jpeg",
        "csv" | "txt" => "text/plain; charset=utf-8",
        "glb" => "model/gltf-binary",
        _ => "application/octet-stream",
    }
}

/// The file a request path names under `root`, or `None` for paths that leave
/// it or name no file.
fn resolve(root: &Path, target: &str) -> Option<PathBuf> {
    let path = target.split(['?', '#']).next().unwrap_or("");
    let path = crate::fsutil::percent_decode(path)?;
    let rel = path.trim_start_matches('/');
    let rel = if rel.is_empty() || rel.ends_with('/') {
        format!("{rel}index.html")
    } else {
        rel.to_string()
    };
    let rel = Path::new(&rel);
    if !rel.components().all(|c| matches!(c, Component::Normal(_))) {
        return None;
    }
    let full = root.join(rel).canonicalize().ok()?;
    (full.starts_with(root) && full.is_file()).then_some(full)
}

fn respond(
    s: &mut TcpStream,
    status: &str,
    kind: &str,
    body: &[u8],
    head_only: bool,
) -> std::io::Result<()> {
    write!(
        s,
        "HTTP/1.1 {status}\r\nContent-Type: {kind}\r\nContent-Length: {}\r\nCache-Control: no-cache\r\nConnection: close\r\n\r\n",
        body.len()
    )?;
    if !head_only {
        s.write_all(body)?;
    }
    s.flush()
}

fn handle(mut stream: TcpStream, root: &Path) -> std::io::Result<()> {
    stream.set_read_timeout(Some(Duration::from_secs(10)))?;
    let mut reader = BufReader::new(stream.try_clone()?.take(MAX_HEAD_BYTES as u64));
    let mut line = String::new();
    reader.read_line(&mut line)?;
    // The headers are read and ignored (up to the limit).
    loop {
        let mut h = String::new();
        if reader.read_line(&mut h)? == 0 || h == "\r\n" || h == "\n" {
            break;
        }
    }
    let mut parts = line.split_whitespace();
    let (method, target) = (parts.next().unwrap_or(""), parts.next().unwrap_or(""));
    let head_only = method == "HEAD";
    if method != "GET" && !head_only {
        return respond(
            &mut stream,
            "405 Method Not Allowed",
            "text/plain",
            b"GET only\n",
            false,
        );
    }
    match resolve(root, target) {
        Some(path) => match std::fs::read(&path) {
            Ok(body) => respond(&mut stream, "200 OK", content_type(&path), &body, head_only),
            Err(_) => respond(
                &mut stream,
                "404 Not Found",
                "text/plain",
                b"not found\n",
                head_only,
            ),
        },
        None => respond(
            &mut stream,
            "404 Not Found",
            "text/plain",
            b"not found\n",
            head_only,
        ),
    }
}

#[cfg(test)]
mod tests {
    use super::*;

    fn get(url_path: &str, addr: std::net::SocketAddr) -> String {
        let mut s = TcpStream::connect(addr).unwrap();
        write!(s, "GET {url_path} HTTP/1.1\r\nHost: x\r\n\r\n").unwrap();
        let mut out = String::new();
        s.read_to_string(&mut out).unwrap();
        out
    }

    #[test]
    fn serves_files_inside_its_folder_and_nothing_outside() {
        let dir = tempfile::tempdir().unwrap();
        let root = dir.path().join("site");
        std::fs::create_dir_all(root.join("a")).unwrap();
        std::fs::write(root.join("index.html"), "<p>hi</p>").unwrap();
        std::fs::write(root.join("a/b c.js"), "x=1").unwrap();
        std::fs::write(dir.path().join("secret.txt"), "no").unwrap();
        let server = serve(&root, 0).unwrap();
        let addr = server.listener.local_addr().unwrap();
        assert!(server.url().unwrap().starts_with("http://127.0.0.1:"));
        std::thread::spawn(move || server.run());
        let r = get("/", addr);
        assert!(
            r.starts_with("HTTP/1.1 200") && r.contains("text/html") && r.ends_with("<p>hi</p>"),
            "{r}"
        );
        let r = get("/a/b%20c.js?v=1", addr);
        assert!(r.contains("text/javascript") && r.ends_with("x=1"), "{r}");
        for bad in [
            "/../secret.txt",
            "/a/../../secret.txt",
            "/%2e%2e/secret.txt",
            "/missing",
            "/%zz",
        ] {
            assert!(get(bad, addr).starts_with("HTTP/1.1 404"), "{bad}");
        }
        let mut s = TcpStream::connect(addr).unwrap();
        write!(s, "POST / HTTP/1.1\r\n\r\n").unwrap();
        let mut out = String::new();
        s.read_to_string(&mut out).unwrap();
        assert!(out.starts_with("HTTP/1.1 405"));
    }
}
