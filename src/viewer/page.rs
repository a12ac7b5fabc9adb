//! The built-in page: a small HTTP server (tiny_http) that serves the files of `web/`, compiled
//! into the binary, so the page works offline; `config.json` tells it the WebSocket port.

use std::sync::Arc;
use std::thread::JoinHandle;

use tiny_http::{Header, Response, Server};

use super::{ViewerConfig, ViewerError};

/// The page's files: (path, content type, bytes).
const FILES: &[(&str, &str, &[u8])] = &[
    (
        "/index.html",
        "text/html; charset=utf-8",
        include_bytes!("web/index.html"),
    ),
    (
        "/viewer.js",
        "text/javascript; charset=utf-8",
        include_bytes!("web/viewer.js"),
    ),
    (
        "/three.module.min.js",
        "text/javascript; charset=utf-8",
        include_bytes!("web/three.module.min.js"),
    ),
    (
        "/OrbitControls.js",
        "text/javascript; charset=utf-8",
        include_bytes!("web/OrbitControls.js"),
    ),
    (
        "/LICENSE.three.txt",
        "text/plain; charset=utf-8",
        include_bytes!("web/LICENSE.three.txt"),
    ),
];

/// The page server's thread; dropping it stops the server.
pub(super) struct PageServer {
    server: Arc<Server>,
    thread: Option<JoinHandle<()>>,
}

fn header(name: &str, value: &str) -> Option<Header> {
    Header::from_bytes(name.as_bytes(), value.as_bytes()).ok()
}

impl PageServer {
    pub(super) fn start(config: &ViewerConfig) -> Result<Self, ViewerError> {
        let port = config.page_port()?;
        let server =
            Server::http((config.address.as_str(), port)).map_err(|e| ViewerError::Page {
                address: config.address.clone(),
                port,
                reason: e.to_string(),
            })?;
        let server = Arc::new(server);
        let ws_port = config.port;
        let thread = {
            let server = Arc::clone(&server);
            std::thread::Builder::new()
                .name("sweepdepth-page".into())
                .spawn(move || serve(&server, ws_port))
                .map_err(|e| ViewerError::Thread(e.to_string()))?
        };
        Ok(Self {
            server,
            thread: Some(thread),
        })
    }
}

fn serve(server: &Server, ws_port: u16) {
    for request in server.incoming_requests() {
        let path = request.url().split('?').next().unwrap_or("/").to_string();
        let path = if path == "/" { "/index.html" } else { &path };
        let response = if path == "/config.json" {
            let body = format!("{{\"websocket_port\":{ws_port}}}");
            Response::from_data(body.into_bytes())
                .maybe_header(header("Content-Type", "application/json"))
        } else if let Some((_, kind, bytes)) = FILES.iter().find(|(p, _, _)| *p == path) {
            Response::from_data(bytes.to_vec()).maybe_header(header("Content-Type", kind))
        } else {
            Response::from_data(b"not found".to_vec()).with_status_code(404)
        };
        let response = response.maybe_header(header("Cache-Control", "no-store"));
        if let Err(e) = request.respond(response) {
            tracing::debug!("viewer page: {e}");
        }
    }
}

/// `Response::with_header` takes a `Header`; an invalid one (never: the names are constants) is left out.
trait MaybeHeader {
    fn maybe_header(self, header: Option<Header>) -> Self;
}

impl<R: std::io::Read> MaybeHeader for Response<R> {
    fn maybe_header(self, header: Option<Header>) -> Self {
        match header {
            Some(h) => Response::with_header(self, h),
            None => self,
        }
    }
}

impl Drop for PageServer {
    fn drop(&mut self) {
        self.server.unblock();
        if let Some(thread) = self.thread.take() {
            let _ = thread.join();
        }
    }
}
