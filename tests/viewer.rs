//! The run viewer (`--html`): a self-contained page whose data match the run, and, in headless
//! Chromium driven over WebDriver, a slider that really redraws the map.

use std::io::{Read, Write};
use std::net::{TcpListener, TcpStream};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

use base64::Engine;
use serde_json::{Value, json};

use crate::common::{assert_clean_failure, plumenet, plumenet_ok, read_json};

const CHROMIUM: &str = "/usr/bin/chromium";
const CHROMEDRIVER: &str = "/usr/bin/chromedriver";

/// The JSON embedded in a viewer page.
fn page_data(html: &str) -> Value {
    let open = r#"<script id="plumenet-data" type="application/json">"#;
    let start = html.find(open).expect("data element") + open.len();
    let len = html[start..].find("</script>").expect("end of data");
    serde_json::from_str(&html[start..start + len]).expect("data is JSON")
}

/// A short solver run of the paper scenario with the viewer, its JSON and the page's path.
fn localize_with_viewer(dir: &Path) -> (Value, PathBuf) {
    let html = dir.join("viewer.html");
    let json_path = dir.join("run.json");
    let cache = dir.join("cache");
    plumenet_ok(&[
        "localize",
        "--solver",
        "--source",
        "4.5,2.5",
        "--start",
        "15,1",
        "--seed",
        "0",
        "--max-iterations",
        "5",
        "--cache-dir",
        cache.to_str().unwrap(),
        "--json",
        json_path.to_str().unwrap(),
        "--html",
        html.to_str().unwrap(),
    ]);
    let run = read_json(&json_path);
    (run, html)
}

#[test]
fn the_run_viewer_is_self_contained_and_matches_the_run() {
    let tmp = tempfile::tempdir().unwrap();
    let (run, html_path) = localize_with_viewer(tmp.path());
    let html = std::fs::read_to_string(&html_path).unwrap();
    assert!(html.len() < 5_000_000, "{} bytes", html.len());
    // Self-contained: nothing is fetched.
    for needle in ["http://", "https://", "src=", "@import", "url("] {
        assert!(!html.contains(needle), "the page refers to {needle}");
    }
    let data = page_data(&html);
    let frames = data["frames"].as_array().unwrap();
    let iterations = run["iterations"].as_u64().unwrap() as usize;
    assert_eq!(frames.len(), iterations);
    let candidates = data["candidates"].as_array().unwrap().len();
    let history = run["history"].as_array().unwrap();
    for (f, h) in frames.iter().zip(history) {
        assert_eq!(f["iteration"], h["iteration"]);
        assert_eq!(f["readings"], h["samples"]);
        assert_eq!(f["estimate"], h["estimate"]);
        let post = f["posterior"].as_array().unwrap();
        assert_eq!(post.len(), candidates);
        // Stored relative to the iteration's maximum: the MAP candidate holds 1000.
        assert_eq!(post.iter().filter_map(Value::as_u64).max(), Some(1000));
        let source = run["source"].as_array().unwrap();
        let err = (f["estimate"][0].as_f64().unwrap() - source[0].as_f64().unwrap())
            .hypot(f["estimate"][1].as_f64().unwrap() - source[1].as_f64().unwrap());
        assert!((f["error_m"].as_f64().unwrap() - err).abs() < 1e-9);
    }
    let last = frames.last().unwrap();
    assert_eq!(last["estimate"], run["estimate"]);
    assert_eq!(
        last["feature"].as_array().unwrap().len(),
        run["samples"].as_array().unwrap().len(),
        "a short run draws every reading"
    );
}

/// Loads the page in headless Chromium over WebDriver, moves the slider with the keyboard and
/// checks that another iteration was drawn (the page writes the drawn iteration and a digest of
/// the map's pixels into the DOM); saves a screenshot. It needs a browser, so the test command
/// lists it as ignored; `-- --ignored` runs it (CI does), and there a missing browser fails it.
#[test]
#[ignore = "needs Chromium and ChromeDriver (Debian chromium, chromium-driver); run with -- --ignored"]
fn the_run_viewer_moves_in_a_browser() {
    let missing: Vec<&str> = [CHROMIUM, CHROMEDRIVER]
        .into_iter()
        .filter(|p| !Path::new(p).exists())
        .collect();
    assert!(
        missing.is_empty(),
        "{} not installed (Debian packages chromium and chromium-driver)",
        missing.join(" and ")
    );
    let tmp = tempfile::tempdir().unwrap();
    let (run, page) = localize_with_viewer(tmp.path());
    let iterations = run["iterations"].as_u64().unwrap() as usize;
    let profile = tempfile::tempdir().unwrap();
    let driver = Driver::start(profile.path());
    let url = format!("file://{}", page.canonicalize().unwrap().display());
    driver.post("url", json!({ "url": url }));
    let body = driver.find("body");
    let map = driver.find("#map");
    let slider = driver.find("#slider");
    let label = driver.find("#iteration");
    let drawn = || driver.attribute(&body, "data-drawn-iteration");
    let digest = || driver.attribute(&map, "data-checksum");

    // The page opens at the last iteration.
    assert_eq!(drawn(), iterations.to_string());
    let last_digest = digest();
    // Home, then one step right, on the focused slider.
    driver.keys(&slider, "\u{E011}");
    assert_eq!(drawn(), "1");
    assert_eq!(driver.text(&label), format!("iteration 1 / {iterations}"));
    let first_digest = digest();
    assert_ne!(first_digest, last_digest, "the map was not redrawn");
    driver.keys(&slider, "\u{E014}");
    assert_eq!(drawn(), "2");
    assert_ne!(digest(), first_digest);

    let shot = driver.screenshot();
    let img = image::load_from_memory(&shot).expect("the screenshot is a PNG");
    assert!(img.width() > 400 && img.height() > 300);
    let colours: std::collections::HashSet<[u8; 3]> = img.to_rgb8().pixels().map(|p| p.0).collect();
    assert!(
        colours.len() > 50,
        "a blank page: {} colours",
        colours.len()
    );
    let out = Path::new(env!("CARGO_TARGET_TMPDIR")).join("viewer-screenshot.png");
    std::fs::write(&out, &shot).unwrap();
    eprintln!("viewer screenshot: {}", out.display());
}

/// A chromedriver process and one WebDriver session in headless Chromium.
struct Driver {
    process: Child,
    port: u16,
    session: String,
}

const ELEMENT: &str = "element-6066-11e4-a52e-4f735466cecf";

impl Driver {
    fn start(profile: &Path) -> Self {
        let port = TcpListener::bind("127.0.0.1:0")
            .unwrap()
            .local_addr()
            .unwrap()
            .port();
        let process = Command::new(CHROMEDRIVER)
            .arg(format!("--port={port}"))
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("chromedriver starts");
        let mut driver = Self {
            process,
            port,
            session: String::new(),
        };
        let deadline = Instant::now() + Duration::from_secs(20);
        while TcpStream::connect(("127.0.0.1", port)).is_err() {
            assert!(Instant::now() < deadline, "chromedriver did not listen");
            std::thread::sleep(Duration::from_millis(100));
        }
        let caps = json!({ "capabilities": { "alwaysMatch": {
            "browserName": "chrome",
            "goog:chromeOptions": {
                "binary": CHROMIUM,
                "args": [
                    "--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
                    "--disable-quic", "--no-first-run", "--disable-background-networking",
                    "--disable-component-update", "--disable-sync", "--window-size=1100,900",
                    format!("--user-data-dir={}", profile.display()),
                ],
            },
        }}});
        let reply = driver.http("POST", "/session", Some(&caps));
        driver.session = reply["value"]["sessionId"]
            .as_str()
            .unwrap_or_else(|| panic!("no session: {reply}"))
            .to_string();
        driver
    }

    /// One WebDriver request (HTTP/1.1, one connection each).
    fn http(&self, method: &str, path: &str, body: Option<&Value>) -> Value {
        let body = body.map(Value::to_string).unwrap_or_default();
        let mut stream = TcpStream::connect(("127.0.0.1", self.port)).unwrap();
        stream
            .set_read_timeout(Some(Duration::from_secs(60)))
            .unwrap();
        write!(
            stream,
            "{method} {path} HTTP/1.1\r\nHost: 127.0.0.1:{}\r\nContent-Type: application/json\r\nContent-Length: {}\r\nConnection: close\r\n\r\n{body}",
            self.port,
            body.len()
        )
        .unwrap();
        // Read the head, then as many bytes as it announces (the driver may keep the
        // connection open), or to the end for a chunked reply.
        let mut reply = Vec::new();
        let mut buf = [0u8; 65536];
        let split = loop {
            if let Some(p) = reply.windows(4).position(|w| w == b"\r\n\r\n") {
                break p;
            }
            let n = stream.read(&mut buf).unwrap();
            assert!(n > 0, "the driver closed the connection mid-reply");
            reply.extend_from_slice(&buf[..n]);
        };
        let head = String::from_utf8_lossy(&reply[..split]).to_ascii_lowercase();
        let mut payload = reply[split + 4..].to_vec();
        let length = head.lines().find_map(|l| {
            l.strip_prefix("content-length:")
                .and_then(|v| v.trim().parse::<usize>().ok())
        });
        match length {
            Some(length) => {
                while payload.len() < length {
                    let n = stream.read(&mut buf).unwrap();
                    assert!(n > 0, "the driver closed the connection mid-reply");
                    payload.extend_from_slice(&buf[..n]);
                }
            }
            None => {
                stream.read_to_end(&mut payload).unwrap();
                if head.contains("transfer-encoding: chunked") {
                    payload = dechunk(&payload);
                }
            }
        }
        let value: Value = serde_json::from_slice(&payload).expect("a JSON reply");
        assert!(
            value["value"].get("error").is_none(),
            "{method} {path}: {value}"
        );
        value
    }

    fn post(&self, what: &str, body: Value) -> Value {
        self.http(
            "POST",
            &format!("/session/{}/{what}", self.session),
            Some(&body),
        )
    }

    fn get(&self, what: &str) -> Value {
        self.http("GET", &format!("/session/{}/{what}", self.session), None)
    }

    fn find(&self, css: &str) -> String {
        let reply = self.post("element", json!({ "using": "css selector", "value": css }));
        reply["value"][ELEMENT].as_str().unwrap().to_string()
    }

    fn attribute(&self, element: &str, name: &str) -> String {
        let reply = self.get(&format!("element/{element}/attribute/{name}"));
        reply["value"].as_str().unwrap_or_default().to_string()
    }

    fn text(&self, element: &str) -> String {
        self.get(&format!("element/{element}/text"))["value"]
            .as_str()
            .unwrap()
            .to_string()
    }

    fn keys(&self, element: &str, keys: &str) {
        self.post(&format!("element/{element}/value"), json!({ "text": keys }));
    }

    fn screenshot(&self) -> Vec<u8> {
        let reply = self.get("screenshot");
        base64::engine::general_purpose::STANDARD
            .decode(reply["value"].as_str().unwrap())
            .unwrap()
    }
}

impl Drop for Driver {
    fn drop(&mut self) {
        if !self.session.is_empty() {
            let _ = std::panic::catch_unwind(std::panic::AssertUnwindSafe(|| {
                self.http("DELETE", &format!("/session/{}", self.session), None)
            }));
        }
        let _ = self.process.kill();
        let _ = self.process.wait();
    }
}

/// The body of a chunked HTTP reply.
fn dechunk(mut data: &[u8]) -> Vec<u8> {
    let mut out = Vec::new();
    while let Some(eol) = data.windows(2).position(|w| w == b"\r\n") {
        let size = usize::from_str_radix(String::from_utf8_lossy(&data[..eol]).trim(), 16)
            .expect("a chunk size");
        if size == 0 {
            break;
        }
        out.extend_from_slice(&data[eol + 2..eol + 2 + size]);
        data = &data[eol + 2 + size + 2..];
    }
    out
}

#[test]
fn replay_shows_its_steps_and_ends_where_the_one_shot_replay_ends() {
    let tmp = tempfile::tempdir().unwrap();
    let log = tmp.path().join("log.csv");
    let mut csv = String::from("t,x,y,value\n");
    for k in 0..60 {
        let x = 2.0 + 0.25 * f64::from(k);
        let y = 1.0 + 0.03 * f64::from(k);
        csv.push_str(&format!(
            "{},{x},{y},{}\n",
            f64::from(k) * 0.5,
            1.0 / (1.0 + (x - 6.0).abs() + (y - 2.0).abs())
        ));
    }
    std::fs::write(&log, csv).unwrap();
    let replay = |extra: &[&str]| {
        let log = log.to_str().unwrap();
        let mut args = vec!["replay", "--solver", "--no-cache", "--log", log];
        args.extend_from_slice(extra);
        plumenet(&args)
    };
    let run = |extra: &[&str], json: &Path| {
        let json = json.to_str().unwrap();
        let mut args = vec!["--source", "6,2", "--json", json];
        args.extend_from_slice(extra);
        let out = replay(&args);
        assert!(
            out.status.success(),
            "{}",
            String::from_utf8_lossy(&out.stderr)
        );
        serde_json::from_str::<Value>(&std::fs::read_to_string(json).unwrap()).unwrap()
    };
    let once = run(&[], &tmp.path().join("once.json"));
    let page = tmp.path().join("replay.html");
    let stepped = run(
        &["--html", page.to_str().unwrap(), "--html-steps", "7"],
        &tmp.path().join("stepped.json"),
    );
    // Taking the readings in chunks ends with the same estimate and posterior.
    assert_eq!(once["estimate"], stepped["estimate"]);
    let post = |v: &Value| -> Vec<f64> {
        v["posterior"]
            .as_array()
            .unwrap()
            .iter()
            .map(|p| p["p"].as_f64().unwrap())
            .collect()
    };
    for (a, b) in post(&once).iter().zip(post(&stepped)) {
        assert!((a - b).abs() < 1e-9, "{a} vs {b}");
    }
    let data = page_data(&std::fs::read_to_string(&page).unwrap());
    let frames = data["frames"].as_array().unwrap();
    assert_eq!(frames.len(), 7);
    let readings: Vec<u64> = frames
        .iter()
        .map(|f| f["readings"].as_u64().unwrap())
        .collect();
    assert_eq!(readings, [9, 18, 27, 36, 45, 54, 60]);
    assert_eq!(frames[6]["estimate"], stepped["estimate"]);
    assert_eq!(data["source"], json!([6.0, 2.0]));
    assert!(
        (frames[6]["error_m"].as_f64().unwrap() - stepped["error_m"].as_f64().unwrap()).abs()
            < 1e-12
    );

    // Bad output paths are one clear error.
    let blocked = tmp.path().join("file");
    std::fs::write(&blocked, "").unwrap();
    let under_a_file = blocked.join("viewer.html");
    let out = replay(&["--html", under_a_file.to_str().unwrap()]);
    assert_clean_failure(&out, "viewer.html");
    assert_clean_failure(&out, "is a file, not a directory");
    let out = replay(&["--png", blocked.join("belief.png").to_str().unwrap()]);
    assert_clean_failure(&out, "belief.png");
}

/// A long run in the largest room stays small: 30 iterations over 5168 candidates and 30000
/// readings make a page under 5 MB that draws at most 2000 readings per iteration.
#[test]
fn a_long_run_in_a_large_room_makes_a_small_page() {
    use plumenet::layout::Layout;
    use plumenet::ste::features::{Feature, FeatureParams};
    use plumenet::ste::posterior::Sample;
    use plumenet::viewer::{MAX_READINGS_SHOWN, RunView, ViewerFrame};
    let layout = Layout::load(&crate::common::repo_path(
        "data/layouts/rooms/hall-30x12.json",
    ))
    .unwrap();
    let candidates = layout.candidates(0.25).unwrap();
    let samples: Vec<Sample> = (0..30_000)
        .map(|k| {
            let t = f64::from(k) * 0.1;
            let x = 0.5 + 29.0 * (t / 3000.0);
            Sample {
                t,
                x,
                y: 6.0,
                value: (t * 0.37).sin(),
            }
        })
        .collect();
    let frames: Vec<ViewerFrame> = (1..=30)
        .map(|i| ViewerFrame {
            iteration: i,
            samples: 1000 * i,
            trajectory: 1000 * i,
            entropy: 8.0 / i as f64,
            estimate: [15.0, 6.0],
            posterior: (0..candidates.len())
                .map(|k| ((k * i) % 97) as f64)
                .collect(),
        })
        .collect();
    let view = RunView {
        title: "hall".into(),
        layout: &layout,
        candidates: &candidates,
        spacing_m: 0.25,
        feature: Feature::Rank,
        feature_params: FeatureParams::default(),
        samples: &samples,
        trajectory: samples.iter().map(|s| [s.x, s.y]).collect(),
        source: Some([10.0, 6.0]),
        frames,
    };
    let html = view.html().unwrap();
    assert!(html.len() < 5_000_000, "{} bytes", html.len());
    let data = page_data(&html);
    assert!(data["readings_shown"].as_array().unwrap().len() <= MAX_READINGS_SHOWN);
    for f in data["frames"].as_array().unwrap() {
        assert_eq!(f["posterior"].as_array().unwrap().len(), candidates.len());
        assert!(f["feature"].as_array().unwrap().len() <= MAX_READINGS_SHOWN);
    }
    // A frame whose posterior does not match the candidates is refused.
    let mut bad = view.clone();
    bad.frames[3].posterior.pop();
    let err = bad.html().unwrap_err().to_string();
    assert!(err.contains("iteration 4"), "{err}");
}
