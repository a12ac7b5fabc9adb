//! The built-in page (issue 13) in a real browser: `sweepdepth bag --view` on the built-in
//! Tsukuba sample (tests/fixtures/bags/tsukuba_half.mcap), Debian's Chromium headless (driven
//! over the DevTools protocol) loads the page, the test waits for the marker the page sets when
//! it has drawn a point cloud and a depth image (`document.body.dataset.drawn`), then a
//! screenshot must show a non-empty 3D view and the depth image. With `--mesh` (fusion) the page
//! must draw the whole fused mesh, also when loaded again after the bag ended, and switch
//! between the mesh and the points.
//!
//! Chromium is required: `scripts/setup.sh` installs it (package `chromium`); without it the
//! test fails and says so. No DDS here (`bag` opens none); the servers bind 127.0.0.1, each test
//! in a private network namespace of its own (tests/common/netns.rs), so that the ports it
//! picks are not taken by another process between the pick and the bind. Chromium runs with
//! every background-networking feature off (its flags below), so it opens no connection beyond
//! the page's.

// The live view is the cargo feature `viewer` (on by default).
#![cfg(feature = "viewer")]

use std::io::{BufRead, BufReader, Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Command, Stdio};
use std::sync::{Arc, Mutex};
use std::time::{Duration, Instant};

use crate::common::netns::{in_private_netns, KillOnDrop};

const INNER: &str = "SWEEPDEPTH_TEST_PRIVATE_NETNS";
use serde_json::{json, Value};

fn root() -> PathBuf {
    PathBuf::from(env!("CARGO_MANIFEST_DIR"))
}

fn timeout() -> Duration {
    crate::common::dds::timeout()
}

fn chromium() -> PathBuf {
    for candidate in ["chromium", "chromium-browser"] {
        if let Ok(out) = Command::new("sh")
            .args(["-c", &format!("command -v {candidate}")])
            .output()
        {
            let path = String::from_utf8_lossy(&out.stdout).trim().to_string();
            if out.status.success() && !path.is_empty() {
                return PathBuf::from(path);
            }
        }
    }
    panic!("Chromium is not installed: run scripts/setup.sh (it installs Debian's `chromium`), which this test needs");
}

/// Two free consecutive ports (the WebSocket server's and the page's).
fn free_port_pair() -> u16 {
    for _ in 0..100 {
        let a = TcpListener::bind(("127.0.0.1", 0)).expect("bind");
        let port = a.local_addr().expect("addr").port();
        if port < u16::MAX && TcpListener::bind(("127.0.0.1", port + 1)).is_ok() {
            return port;
        }
    }
    panic!("no two free consecutive ports");
}

/// `sweepdepth bag BAG OUT_DIR/out.mcap --params-file PARAMS --view --view-rate max` serving
/// on `port` (and the page on the next), with `extra` arguments; its stderr piped.
fn bag_view(bag: &Path, params: &Path, out_dir: &Path, port: u16, extra: &[&str]) -> KillOnDrop {
    KillOnDrop(
        Command::new(env!("CARGO_BIN_EXE_sweepdepth"))
            .arg("bag")
            .arg(bag)
            .arg(out_dir.join("out.mcap"))
            .arg("--params-file")
            .arg(params)
            .args([
                "--view",
                "--view-rate",
                "max",
                "-p",
                &format!("foxglove_port:={port}"),
            ])
            .args(extra)
            .stdout(Stdio::null())
            .stderr(Stdio::piped())
            .spawn()
            .expect("start sweepdepth bag --view"),
    )
}

/// `GET path` as JSON. Chromium keeps the connection open: the body is read by its
/// Content-Length.
fn http_get_json(port: u16, path: &str) -> Option<Value> {
    let mut stream = TcpStream::connect(("127.0.0.1", port)).ok()?;
    stream.set_read_timeout(Some(timeout())).ok()?;
    write!(
        stream,
        "GET {path} HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\n\r\n"
    )
    .ok()?;
    let mut response = Vec::new();
    let mut buf = [0u8; 8192];
    loop {
        let n = stream.read(&mut buf).ok()?;
        if n == 0 {
            return None;
        }
        response.extend_from_slice(&buf[..n]);
        let Some(split) = response.windows(4).position(|w| w == b"\r\n\r\n") else {
            continue;
        };
        let head = String::from_utf8_lossy(&response[..split]).to_ascii_lowercase();
        let length: usize = head
            .lines()
            .find_map(|l| l.strip_prefix("content-length:"))
            .and_then(|v| v.trim().parse().ok())?;
        if response.len() >= split + 4 + length {
            return serde_json::from_slice(&response[split + 4..split + 4 + length]).ok();
        }
    }
}

/// Standard base64 (the screenshot's encoding).
fn base64_decode(text: &str) -> Vec<u8> {
    let value = |c: u8| -> u32 {
        match c {
            b'A'..=b'Z' => u32::from(c - b'A'),
            b'a'..=b'z' => u32::from(c - b'a') + 26,
            b'0'..=b'9' => u32::from(c - b'0') + 52,
            b'+' => 62,
            b'/' => 63,
            _ => panic!("not base64: {c}"),
        }
    };
    let bytes: Vec<u8> = text.bytes().filter(|c| *c != b'=').collect();
    let mut out = Vec::with_capacity(bytes.len() * 3 / 4);
    for chunk in bytes.chunks(4) {
        let mut acc = 0u32;
        for (i, c) in chunk.iter().enumerate() {
            acc |= value(*c) << (18 - 6 * i);
        }
        let n = chunk.len() * 6 / 8;
        out.extend_from_slice(&acc.to_be_bytes()[1..1 + n]);
    }
    out
}

/// The DevTools protocol over the page's WebSocket.
struct DevTools {
    ws: tungstenite::WebSocket<tungstenite::stream::MaybeTlsStream<TcpStream>>,
    next_id: u64,
}

impl DevTools {
    fn call(&mut self, method: &str, params: Value) -> Value {
        self.next_id += 1;
        let id = self.next_id;
        let msg = json!({"id": id, "method": method, "params": params});
        self.ws
            .send(tungstenite::Message::Text(msg.to_string().into()))
            .expect("DevTools send");
        loop {
            let frame = self.ws.read().expect("DevTools read");
            if let tungstenite::Message::Text(text) = frame {
                let value: Value = serde_json::from_str(&text).expect("DevTools JSON");
                if value["id"] == id {
                    assert!(value.get("error").is_none(), "{method}: {value}");
                    return value["result"].clone();
                }
            }
        }
    }

    fn evaluate(&mut self, expression: &str) -> Value {
        let result = self.call(
            "Runtime.evaluate",
            json!({"expression": expression, "returnByValue": true}),
        );
        result["result"]["value"].clone()
    }
}

/// Pixels of `rect` (CSS px, scaled by `scale`) in `image` that differ from `background`.
fn share_not_background(
    image: &image::RgbaImage,
    rect: &Value,
    scale: f64,
    background: [u8; 3],
) -> f64 {
    let f = |k: &str| rect[k].as_f64().unwrap_or(0.0) * scale;
    let (x0, y0) = (f("x").max(0.0) as u32, f("y").max(0.0) as u32);
    let x1 = ((f("x") + f("width")) as u32).min(image.width());
    let y1 = ((f("y") + f("height")) as u32).min(image.height());
    let mut differ = 0u64;
    let mut total = 0u64;
    for y in y0..y1 {
        for x in x0..x1 {
            let p = image.get_pixel(x, y).0;
            total += 1;
            let d = (0..3)
                .map(|i| p[i].abs_diff(background[i]) as u32)
                .sum::<u32>();
            if d > 24 {
                differ += 1;
            }
        }
    }
    assert!(total > 0, "empty region {rect}");
    differ as f64 / total as f64
}

/// `sweepdepth bag --view` on the Tsukuba sample (with `extra` arguments) and headless Chromium
/// with the page loaded.
struct Session {
    sweepdepth: KillOnDrop,
    _browser: KillOnDrop,
    devtools: DevTools,
    out_dir: PathBuf,
    started: Instant,
    page_url: String,
    /// `sweepdepth`'s stderr so far (also printed).
    stderr: Arc<Mutex<String>>,
}

impl Session {
    fn start(name: &str, extra: &[&str]) -> Self {
        let bag = root().join("tests/fixtures/bags/tsukuba_half.mcap");
        let params = root().join("tests/fixtures/bags/tsukuba_half.params.yaml");
        Self::start_bag(name, &bag, &params, "", extra)
    }

    /// `bag --view` on `bag` with `params`, the page loaded with `query` (`?view=above`, or "").
    fn start_bag(name: &str, bag: &Path, params: &Path, query: &str, extra: &[&str]) -> Self {
        let chromium = chromium();
        let port = free_port_pair();
        let out_dir = std::env::temp_dir().join(format!(
            "sweepdepth-viewer-page-{name}-{}",
            std::process::id()
        ));
        let _ = std::fs::remove_dir_all(&out_dir);
        std::fs::create_dir_all(&out_dir).expect("temp dir");
        let mut sweepdepth = bag_view(bag, params, &out_dir, port, extra);
        let stderr = Arc::new(Mutex::new(String::new()));
        if let Some(pipe) = sweepdepth.0.stderr.take() {
            let stderr = Arc::clone(&stderr);
            std::thread::spawn(move || {
                for line in BufReader::new(pipe).lines().map_while(Result::ok) {
                    eprintln!("{line}");
                    let mut all = stderr.lock().unwrap_or_else(|e| e.into_inner());
                    all.push_str(&line);
                    all.push('\n');
                }
            });
        }
        let profile = out_dir.join("chromium-profile");
        let page_url = format!("http://127.0.0.1:{}/{query}", port + 1);
        let browser = KillOnDrop(
            Command::new(&chromium)
                .args([
                    "--headless",
                    "--no-sandbox",
                    "--disable-gpu",
                    "--enable-unsafe-swiftshader",
                    "--disable-quic",
                    "--no-first-run",
                    "--disable-background-networking",
                    "--disable-component-update",
                    "--disable-sync",
                    "--window-size=1280,800",
                    "--remote-debugging-port=0",
                ])
                .arg(format!("--user-data-dir={}", profile.display()))
                .arg("about:blank")
                .stdout(Stdio::null())
                .stderr(Stdio::null())
                .spawn()
                .expect("start chromium"),
        );
        let started = Instant::now();
        let wait = |what: &str| {
            assert!(
                started.elapsed() < timeout(),
                "waited {:?} for {what} in vain",
                timeout()
            );
            std::thread::sleep(Duration::from_millis(200));
        };
        // Chromium writes its DevTools port into the profile.
        let devtools_port: u16 = loop {
            if let Ok(text) = std::fs::read_to_string(profile.join("DevToolsActivePort")) {
                if let Some(port) = text.lines().next().and_then(|l| l.trim().parse().ok()) {
                    break port;
                }
            }
            wait("Chromium's DevToolsActivePort");
        };
        let target = loop {
            let page = http_get_json(devtools_port, "/json/list").and_then(|list| {
                list.as_array()?
                    .iter()
                    .find(|t| t["type"] == "page")
                    .and_then(|t| t["webSocketDebuggerUrl"].as_str().map(str::to_string))
            });
            if let Some(url) = page {
                break url;
            }
            wait("a Chromium page target");
        };
        let (ws, _) = tungstenite::connect(target.as_str()).expect("DevTools WebSocket");
        let devtools = DevTools { ws, next_id: 0 };
        // The page server is up once `bag --view` has started its viewer.
        loop {
            if TcpStream::connect(("127.0.0.1", port + 1)).is_ok() {
                break;
            }
            if let Some(status) = sweepdepth.0.try_wait().expect("wait") {
                panic!("sweepdepth bag --view ended ({status}) before serving the page");
            }
            wait("the page server");
        }
        let mut session = Self {
            sweepdepth,
            _browser: browser,
            devtools,
            out_dir,
            started,
            page_url,
            stderr,
        };
        session.load();
        session
    }

    fn load(&mut self) {
        let url = self.page_url.clone();
        self.devtools.call("Page.navigate", json!({"url": url}));
    }

    /// The page's state: `drawn`, `mesh` (its markers), `state` (window.sweepdepthState),
    /// `status`, `count`.
    fn state(&mut self) -> Value {
        let state = self.devtools.evaluate(
            "JSON.stringify({old: !!window.sweepdepthOldPage, drawn: document.body && document.body.dataset.drawn || '', mesh: document.body && document.body.dataset.mesh || '', state: window.sweepdepthState || null, status: (document.getElementById('status')||{}).textContent || '', count: (document.getElementById('count')||{}).textContent || ''})",
        );
        serde_json::from_str(state.as_str().unwrap_or("{}")).unwrap_or(Value::Null)
    }

    /// Waits (within the one limit) until `done` holds for the page's state; returns it.
    fn wait_for(&mut self, what: &str, done: impl Fn(&Value) -> bool) -> Value {
        loop {
            let state = self.state();
            if done(&state) {
                return state;
            }
            if let Some(status) = self.sweepdepth.0.try_wait().expect("wait") {
                panic!("sweepdepth bag --view ended ({status}) while the page waited for {what}; page: {state}");
            }
            assert!(
                self.started.elapsed() < timeout(),
                "the page did not show {what} within {:?}; its state: {state}",
                timeout()
            );
            std::thread::sleep(Duration::from_millis(250));
        }
    }

    /// Waits until `sweepdepth`'s stderr has a line containing `needle`; returns that line.
    fn wait_for_stderr(&mut self, needle: &str) -> String {
        loop {
            let line = self
                .stderr
                .lock()
                .unwrap_or_else(|e| e.into_inner())
                .lines()
                .find(|l| l.contains(needle))
                .map(str::to_string);
            if let Some(line) = line {
                return line;
            }
            if let Some(status) = self.sweepdepth.0.try_wait().expect("wait") {
                panic!("sweepdepth bag --view ended ({status}) before printing {needle:?}");
            }
            assert!(
                self.started.elapsed() < timeout(),
                "sweepdepth did not print {needle:?} within {:?}",
                timeout()
            );
            std::thread::sleep(Duration::from_millis(100));
        }
    }

    /// A screenshot (saved at `target/<name>`) and the CSS rectangles of the 3D view and the
    /// depth image.
    fn screenshot(&mut self, name: &str) -> (image::RgbaImage, Value, PathBuf) {
        // Let two more animation frames paint, then look at the pixels.
        self.devtools
            .evaluate("new Promise(r => requestAnimationFrame(() => requestAnimationFrame(r)))");
        let rects: Value = serde_json::from_str(
            self.devtools
                .evaluate("JSON.stringify({cloud: document.querySelector('#cloud canvas').getBoundingClientRect(), depth: document.getElementById('depth').getBoundingClientRect(), scale: window.devicePixelRatio})")
                .as_str()
                .unwrap_or("{}"),
        )
        .expect("rects");
        let shot = self
            .devtools
            .call("Page.captureScreenshot", json!({"format": "png"}));
        let png = base64_decode(shot["data"].as_str().expect("screenshot data"));
        let saved = root().join("target").join(name);
        std::fs::write(&saved, &png).expect("save the screenshot");
        let image = image::load_from_memory(&png).expect("PNG").to_rgba8();
        (image, rects, saved)
    }

    /// `bag --view` ends cleanly on SIGTERM, its output written.
    fn stop(mut self) {
        Command::new("kill")
            .args(["-TERM", &self.sweepdepth.0.id().to_string()])
            .status()
            .expect("kill -TERM");
        let status = self.sweepdepth.0.wait().expect("wait for sweepdepth");
        assert!(
            status.success(),
            "sweepdepth bag --view after SIGTERM: {status}"
        );
        assert!(self.out_dir.join("out.mcap").exists());
        let _ = std::fs::remove_dir_all(&self.out_dir);
    }
}

const BACKGROUND: [u8; 3] = [0x14, 0x16, 0x1a];

#[test]
fn page_draws_the_point_cloud_of_bag_view() {
    in_private_netns(
        INNER,
        "viewer_page::page_draws_the_point_cloud_of_bag_view",
        point_cloud_of_bag_view,
    );
}

fn point_cloud_of_bag_view() {
    let mut session = Session::start("cloud", &[]);
    let state = session.wait_for("a point cloud and a depth image", |s| s["drawn"] == "1");
    eprintln!("page state: {state}");
    assert!(
        state["state"]["points"].as_u64().unwrap_or(0) > 1000,
        "{state}"
    );
    assert!(
        state["state"]["depthFrames"].as_u64().unwrap_or(0) >= 1,
        "{state}"
    );
    assert_eq!(state["state"]["errors"], json!([]), "{state}");
    // Without fusion there is no mesh: the points are shown.
    assert_eq!(state["state"]["show"], "points", "{state}");
    assert_eq!(state["state"]["meshBlocks"], 0, "{state}");

    let (image, rects, saved) = session.screenshot("viewer-page.png");
    let scale = rects["scale"].as_f64().unwrap_or(1.0);
    let cloud = share_not_background(&image, &rects["cloud"], scale, BACKGROUND);
    let depth = share_not_background(&image, &rects["depth"], scale, [0, 0, 0]);
    eprintln!(
        "screenshot {}: 3D view {:.1} % drawn, depth image {:.1} % coloured",
        saved.display(),
        cloud * 100.0,
        depth * 100.0
    );
    assert!(
        cloud > 0.05,
        "the 3D view is (nearly) empty: {:.2} % of it drawn; see {}",
        cloud * 100.0,
        saved.display()
    );
    assert!(
        depth > 0.5,
        "the depth image is (nearly) empty: {:.2} % coloured; see {}",
        depth * 100.0,
        saved.display()
    );
    session.stop();
}

/// Issue 28: `bag --view --mesh`: the page draws the fused mesh (every triangle the bag fused,
/// also when it is loaded again after the bag ended: the viewer sends the whole mesh to a late
/// subscriber, then the deltas), shows it by default, and switches to the points and to both.
#[test]
fn page_draws_the_fused_mesh_of_bag_view() {
    in_private_netns(
        INNER,
        "viewer_page::page_draws_the_fused_mesh_of_bag_view",
        fused_mesh_of_bag_view,
    );
}

fn fused_mesh_of_bag_view() {
    let mesh_file = std::env::temp_dir().join(format!(
        "sweepdepth-viewer-page-mesh-{}.ply",
        std::process::id()
    ));
    let mut session = Session::start("mesh", &["--mesh", mesh_file.to_str().expect("path")]);
    // The bag's mesh, as `bag` reports it once every set is fused and offered.
    let line = session.wait_for_stderr("depth maps fused into");
    let triangles: u64 = line
        .split('(')
        .nth(1)
        .and_then(|rest| rest.split_whitespace().next())
        .and_then(|n| n.parse().ok())
        .unwrap_or_else(|| panic!("no triangle count in {line:?}"));
    assert!(triangles > 10_000, "{line}");
    let complete = |s: &Value| {
        s["old"] == false
            && s["drawn"] == "1"
            && s["mesh"] == "1"
            && s["state"]["meshTriangles"] == triangles
    };
    // Loaded while the bag ran or after: then loaded again, a late subscriber.
    for load in 0..2 {
        if load == 1 {
            session.devtools.evaluate("window.sweepdepthOldPage = true");
            session.load();
            // The new page's state, not the old one's.
            session.wait_for("the reloaded page", |s| s["old"] == false);
        }
        let state = session.wait_for("the whole fused mesh", complete);
        eprintln!("page state (load {load}): {state}");
        assert_eq!(state["state"]["errors"], json!([]), "{state}");
        assert_eq!(state["state"]["show"], "mesh", "{state}");
        assert!(
            state["state"]["meshBlocks"].as_u64().unwrap_or(0) > 100,
            "{state}"
        );
        assert!(
            state["count"]
                .as_str()
                .unwrap_or("")
                .contains("triangles in"),
            "{state}"
        );
    }

    let (image, rects, saved) = session.screenshot("viewer-page-mesh.png");
    let scale = rects["scale"].as_f64().unwrap_or(1.0);
    let drawn = share_not_background(&image, &rects["cloud"], scale, BACKGROUND);
    eprintln!(
        "screenshot {}: 3D view {:.1} % drawn (mesh)",
        saved.display(),
        drawn * 100.0
    );
    assert!(
        drawn > 0.1,
        "the mesh covers only {:.2} % of the 3D view; see {}",
        drawn * 100.0,
        saved.display()
    );

    // The control switches to the points, then to both (the same frame here: the first
    // reference's), each drawn.
    for (show, count) in [("points", "points"), ("both", "triangles in")] {
        session.devtools.evaluate(&format!(
            "(() => {{ const s = document.getElementById('show'); s.value = '{show}'; s.dispatchEvent(new Event('change')); }})()"
        ));
        let state = session.wait_for(show, |s| s["state"]["show"] == show);
        assert!(
            state["count"].as_str().unwrap_or("").contains(count),
            "{state}"
        );
        if show == "points" {
            assert!(
                !state["count"].as_str().unwrap_or("").contains("triangles"),
                "{state}"
            );
        }
        let (image, rects, saved) = session.screenshot(&format!("viewer-page-{show}.png"));
        let drawn = share_not_background(&image, &rects["cloud"], scale, BACKGROUND);
        eprintln!(
            "screenshot {}: 3D view {:.1} % drawn",
            saved.display(),
            drawn * 100.0
        );
        assert!(
            drawn > 0.05,
            "{show}: the 3D view is (nearly) empty; see {}",
            saved.display()
        );
    }
    session.stop();
    let _ = std::fs::remove_file(&mesh_file);
}

/// Issue 29: the Tsukuba sample at full size (384x288, one frame set packed from `data/tsukuba`)
/// in the page, seen from above (`?view=above`), with the defaults and with `subpixel_refine`:
/// the README's screenshots (`docs/viewer-steps-before.png`, `docs/viewer-steps-after.png`).
/// A documentation generator, not run by default: `SWEEPDEPTH_WRITE_DOCS=1 cargo test --release
/// --test live docs_the_steps -- --ignored` (without the variable the screenshots stay in
/// `target/`).
#[test]
#[ignore = "writes the README's screenshots"]
fn docs_the_steps_from_above_before_and_after_the_fine_sweep() {
    let dir = std::env::temp_dir().join(format!("sweepdepth-steps-{}", std::process::id()));
    std::fs::create_dir_all(&dir).expect("temp dir");
    let bag = dir.join("tsukuba.mcap");
    let status = Command::new(env!("CARGO_BIN_EXE_sweepdepth"))
        .arg("pack")
        .arg(root().join("data/tsukuba"))
        .arg(&bag)
        .args(["--frames", "1", "--force"])
        .status()
        .expect("sweepdepth pack");
    assert!(status.success(), "sweepdepth pack: {status}");
    let params = dir.join("tsukuba.params.yaml");
    for (name, refine) in [("before", "false"), ("after", "true")] {
        let refine = format!("subpixel_refine:={refine}");
        let mut session =
            Session::start_bag(name, &bag, &params, "?view=above", &["-p", refine.as_str()]);
        let state = session.wait_for("a point cloud and a depth image", |s| s["drawn"] == "1");
        assert!(
            state["state"]["points"].as_u64().unwrap_or(0) > 50_000,
            "{state}"
        );
        let file = format!("viewer-steps-{name}.png");
        let (image, rects, saved) = session.screenshot(&file);
        let scale = rects["scale"].as_f64().unwrap_or(1.0);
        let cloud = share_not_background(&image, &rects["cloud"], scale, BACKGROUND);
        assert!(
            cloud > 0.05,
            "the 3D view is (nearly) empty; see {}",
            saved.display()
        );
        if std::env::var_os("SWEEPDEPTH_WRITE_DOCS").is_some() {
            std::fs::copy(&saved, root().join("docs").join(&file)).expect("copy to docs/");
        }
        session.stop();
    }
    let _ = std::fs::remove_dir_all(&dir);
}

/// Ctrl-C while `bag --view` holds the last set on view ends the view and says so, with exit
/// status 0 (it used to print the run's "stopping; the sets processed so far are written").
#[test]
fn ctrl_c_on_the_held_view_ends_the_view() {
    in_private_netns(
        INNER,
        "viewer_page::ctrl_c_on_the_held_view_ends_the_view",
        ctrl_c_on_the_held_view,
    );
}

fn ctrl_c_on_the_held_view() {
    let port = free_port_pair();
    let out_dir =
        std::env::temp_dir().join(format!("sweepdepth-view-ctrl-c-{}", std::process::id()));
    let _ = std::fs::remove_dir_all(&out_dir);
    std::fs::create_dir_all(&out_dir).expect("temp dir");
    let mut bag = bag_view(
        &root().join("tests/fixtures/bags/tsukuba_half.mcap"),
        &root().join("tests/fixtures/bags/tsukuba_half.params.yaml"),
        &out_dir,
        port,
        &[],
    );
    let (lines, seen) = std::sync::mpsc::channel();
    if let Some(pipe) = bag.0.stderr.take() {
        std::thread::spawn(move || {
            for line in BufReader::new(pipe).lines().map_while(Result::ok) {
                eprintln!("{line}");
                if lines.send(line).is_err() {
                    break;
                }
            }
        });
    }
    let started = Instant::now();
    let mut log = String::new();
    while !log.contains("stays on view") {
        let left = timeout().saturating_sub(started.elapsed());
        match seen.recv_timeout(left) {
            Ok(line) => log.push_str(&(line + "\n")),
            Err(_) => panic!("no \"stays on view\" within {:?}:\n{log}", timeout()),
        }
    }
    let status = Command::new("kill")
        .args(["-INT", &bag.0.id().to_string()])
        .status()
        .expect("kill");
    assert!(status.success());
    let exit = loop {
        if let Some(exit) = bag.0.try_wait().expect("wait") {
            break exit;
        }
        assert!(
            started.elapsed() < timeout(),
            "bag did not end after Ctrl-C:\n{log}"
        );
        std::thread::sleep(Duration::from_millis(20));
    };
    while let Ok(line) = seen.recv_timeout(Duration::from_secs(5)) {
        log.push_str(&(line + "\n"));
    }
    assert!(exit.success(), "exit {exit}:\n{log}");
    assert!(log.contains("Ctrl-C: the view ends"), "{log}");
    assert!(!log.contains("sets processed so far are written"), "{log}");
    let _ = std::fs::remove_dir_all(&out_dir);
}
