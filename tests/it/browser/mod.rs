//! Headless Chromium driven over WebDriver (chromedriver + fantoccini) for
//! the UI tests. When chromedriver is missing the tests print why and pass,
//! unless `SPRINGBENCH_BROWSER_TESTS=require` (set by `.ci/run`), which makes
//! a missing browser a failure.
#![allow(dead_code)]

use fantoccini::wd::WebDriverCompatibleCommand;
use fantoccini::{Client, ClientBuilder, Locator};
use serde_json::{json, Value};
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Stdio};
use std::time::{Duration, Instant};

/// Browser tests run one at a time (2 cores: one Chromium is load enough).
/// The browser-test macro: `let (mut b, d) = open_browser!(&config);` is
/// [`Browser::open`], and a test without chromedriver returns there (it
/// passes, having said why; `SPRINGBENCH_BROWSER_TESTS=require` makes that a
/// failure instead).
macro_rules! open_browser {
    ($config:expr) => {
        match $crate::browser::Browser::open($config).await {
            Some(open) => open,
            None => return,
        }
    };
}
pub(crate) use open_browser;

pub static ONE_AT_A_TIME: tokio::sync::Mutex<()> = tokio::sync::Mutex::const_new(());

fn which(name: &str) -> Option<PathBuf> {
    let path = std::env::var_os("PATH")?;
    std::env::split_paths(&path)
        .map(|d| d.join(name))
        .find(|p| p.is_file())
}

/// The chromedriver to use, or None with the reason (a failure when required).
pub fn chromedriver() -> Option<PathBuf> {
    let found = std::env::var_os("CHROMEDRIVER")
        .map(PathBuf::from)
        .filter(|p| p.is_file())
        .or_else(|| which("chromedriver"));
    if found.is_none() {
        let msg = "chromedriver not found (apt-get install chromium chromium-driver): browser test skipped";
        if std::env::var("SPRINGBENCH_BROWSER_TESTS").as_deref() == Ok("require") {
            panic!("{msg}, but SPRINGBENCH_BROWSER_TESTS=require");
        }
        eprintln!("{msg}");
    }
    found
}

fn chromium_binary() -> String {
    if let Ok(b) = std::env::var("CHROMIUM_BINARY") {
        return b;
    }
    // Debian's /usr/bin/chromium is a wrapper script; the real binary is beside it.
    for p in ["/usr/lib/chromium/chromium", "/usr/bin/chromium"] {
        if Path::new(p).is_file() {
            return p.to_string();
        }
    }
    "chromium".into()
}

/// Where screenshots go: `$SPRINGBENCH_UI_ARTIFACTS` or `target/ui-artifacts`.
pub fn artifacts_dir() -> PathBuf {
    let d = std::env::var_os("SPRINGBENCH_UI_ARTIFACTS")
        .map(PathBuf::from)
        .unwrap_or_else(|| Path::new(env!("CARGO_MANIFEST_DIR")).join("target/ui-artifacts"));
    std::fs::create_dir_all(&d).expect("create the artifacts directory");
    d
}

/// `POST /session/{id}/se/log {"type": "browser"}`: the console messages since the last call.
#[derive(Debug)]
struct BrowserLog;

impl WebDriverCompatibleCommand for BrowserLog {
    fn endpoint(
        &self,
        base_url: &url::Url,
        session_id: Option<&str>,
    ) -> Result<url::Url, url::ParseError> {
        base_url.join(&format!("session/{}/se/log", session_id.unwrap_or("")))
    }
    fn method_and_body(&self, _: &url::Url) -> (http::Method, Option<String>) {
        (http::Method::POST, Some(r#"{"type":"browser"}"#.into()))
    }
}

pub struct Browser {
    pub c: Client,
    driver: Child,
    _profile: tempfile::TempDir,
    /// Every console message seen so far (level, source, message).
    pub log: Vec<Value>,
    /// [`ONE_AT_A_TIME`], held by a browser from [`Browser::open`].
    _one: Option<tokio::sync::MutexGuard<'static, ()>>,
    /// The daemon of [`Browser::open`] (`http://127.0.0.1:PORT`), for [`Browser::visit`].
    pub base: String,
}

impl Browser {
    /// Starts chromedriver and a headless Chromium (1280x800); None when
    /// chromedriver is not installed (see [`chromedriver`]).
    pub async fn start() -> Option<Browser> {
        let driver_bin = chromedriver()?;
        eprintln!("[browser] starting {}", driver_bin.display());
        let port = {
            let l = std::net::TcpListener::bind("127.0.0.1:0").expect("free port");
            l.local_addr().unwrap().port()
        };
        // Own process group: a failed test kills chromedriver and its Chromium together.
        use std::os::unix::process::CommandExt;
        let driver = Command::new(&driver_bin)
            .arg(format!("--port={port}"))
            .process_group(0)
            .stdout(Stdio::null())
            .stderr(Stdio::null())
            .spawn()
            .expect("start chromedriver");
        let profile = tempfile::tempdir().expect("profile dir");
        let base = format!("http://127.0.0.1:{port}");
        let http = reqwest::Client::new();
        let t = Instant::now();
        loop {
            if let Ok(r) = http.get(format!("{base}/status")).send().await {
                if let Ok(v) = r.json::<Value>().await {
                    if v["value"]["ready"] == json!(true) {
                        break;
                    }
                }
            }
            assert!(
                t.elapsed() < Duration::from_secs(30),
                "chromedriver did not become ready within 30 s"
            );
            tokio::time::sleep(Duration::from_millis(50)).await;
        }
        let args = vec![
            "--headless".to_string(),
            "--no-sandbox".into(),
            "--disable-gpu".into(),
            "--disable-quic".into(),
            "--no-first-run".into(),
            "--disable-background-networking".into(),
            "--disable-component-update".into(),
            "--disable-sync".into(),
            "--disable-dev-shm-usage".into(),
            "--window-size=1280,800".into(),
            "--hide-scrollbars".into(),
            format!("--user-data-dir={}", profile.path().display()),
        ];
        let caps = json!({
            "browserName": "chrome",
            "goog:chromeOptions": {"binary": chromium_binary(), "args": args},
            "goog:loggingPrefs": {"browser": "ALL"},
        });
        let caps = caps.as_object().unwrap().clone();
        let c = ClientBuilder::new(hyper_util::client::legacy::connect::HttpConnector::new())
            .capabilities(caps)
            .connect(&base)
            .await
            .expect("start a Chromium session");
        eprintln!("[browser] Chromium session started");
        // A 1280x800 viewport (the station screen), whatever the window decorations take.
        let inner = c
            .execute("return [window.innerWidth, window.innerHeight];", vec![])
            .await
            .expect("viewport size");
        let (w, h) = (
            inner[0].as_u64().unwrap_or(1280) as u32,
            inner[1].as_u64().unwrap_or(800) as u32,
        );
        if (w, h) != (1280, 800) {
            let (ow, oh) = c.get_window_size().await.expect("window size");
            let _ = c
                .set_window_size(ow as u32 + 1280 - w, oh as u32 + 800 - h)
                .await;
        }
        Some(Browser {
            c,
            driver,
            _profile: profile,
            log: vec![],
            _one: None,
            base: String::new(),
        })
    }

    /// A browser test's start: waits for the other browser tests
    /// ([`ONE_AT_A_TIME`], held until this browser is dropped), starts the
    /// browser, then the daemon with `config`; None (the test passes, having
    /// said why) without chromedriver.
    pub async fn open(config: &str) -> Option<(Browser, crate::common::Daemon)> {
        let one = ONE_AT_A_TIME.lock().await;
        let mut b = Browser::start().await?;
        let d = crate::common::Daemon::start(config);
        b._one = Some(one);
        b.base = d.base.clone();
        Some((b, d))
    }

    /// A browser test's end: no console error `when`, then the browser quits.
    pub async fn finish(mut self, when: &str) {
        self.assert_no_console_errors(when).await;
        self.quit().await;
    }

    /// Opens the page `hash` (`#/qc`) of the daemon and waits up to
    /// `timeout` for `expr` (see [`Browser::wait_js`]).
    pub async fn visit(&self, hash: &str, timeout: Duration, what: &str, expr: &str) -> Value {
        self.goto(&format!("{}/{hash}", self.base)).await;
        self.wait_js(expr, timeout, what).await
    }

    /// [`Browser::wait_js`] with 20 s.
    pub async fn wait(&self, what: &str, expr: &str) -> Value {
        self.wait_js(expr, Duration::from_secs(20), what).await
    }

    /// [`Browser::wait_js`] with 120 s (a measurement, a fit).
    pub async fn wait_long(&self, what: &str, expr: &str) -> Value {
        self.wait_js(expr, Duration::from_secs(120), what).await
    }

    /// Waits for the element `css` (20 s).
    pub async fn wait_for(&self, css: &str) -> Value {
        let expr = format!("document.querySelector('{}')", css.replace('\'', "\\'"));
        self.wait_js(&expr, Duration::from_secs(20), css).await
    }

    /// Waits for the confirmation dialog (20 s) and answers it.
    pub async fn confirm(&self, yes: bool) {
        self.wait_js(
            "document.querySelector('#confirm').open",
            Duration::from_secs(20),
            "the confirmation",
        )
        .await;
        self.click(if yes { "#confirm-yes" } else { "#confirm-no" })
            .await;
    }

    /// Runs `script` for its effect (it returns true).
    pub async fn run(&self, script: &str) {
        self.js(&format!("{script} return true;"), vec![]).await;
    }

    /// Collects the console messages since the last call into `self.log`; returns the new ones.
    pub async fn drain_log(&mut self) -> Vec<Value> {
        let v = self
            .c
            .issue_cmd(BrowserLog)
            .await
            .expect("read the browser log");
        let new: Vec<Value> = v.as_array().cloned().unwrap_or_default();
        self.log.extend(new.iter().cloned());
        new
    }

    /// Fails on any console message of level SEVERE (errors, failed loads, CSP violations).
    pub async fn assert_no_console_errors(&mut self, when: &str) {
        self.assert_no_console_errors_but(when, |_| false).await;
    }

    /// The same, except the SEVERE messages that `expected` accepts (by
    /// their text: a refusal the test provoked on purpose).
    pub async fn assert_no_console_errors_but(
        &mut self,
        when: &str,
        expected: impl Fn(&str) -> bool,
    ) {
        let new = self.drain_log().await;
        let errors: Vec<&Value> = new
            .iter()
            .filter(|e| {
                e["level"] == "SEVERE" && !expected(e["message"].as_str().unwrap_or_default())
            })
            .collect();
        assert!(
            errors.is_empty(),
            "browser console errors {when}: {errors:#?}"
        );
    }

    pub async fn goto(&self, url: &str) {
        self.c.goto(url).await.expect("navigate");
    }

    /// Runs `script` (a function body; `arguments` available) and returns its value.
    pub async fn js(&self, script: &str, args: Vec<Value>) -> Value {
        self.c
            .execute(script, args)
            .await
            .unwrap_or_else(|e| panic!("script failed: {e}\n{script}"))
    }

    /// Polls `expr` (a JS expression) until it is truthy; returns its value.
    pub async fn wait_js(&self, expr: &str, timeout: Duration, what: &str) -> Value {
        eprintln!("[browser] waiting for {what}");
        let t = Instant::now();
        let script = format!("try {{ return ({expr}); }} catch (e) {{ return null; }}");
        loop {
            // An error (e.g. while the page reloads) counts as "not yet".
            let v = self.c.execute(&script, vec![]).await.unwrap_or(Value::Null);
            let truthy =
                !matches!(&v, Value::Null | Value::Bool(false)) && v != json!(0) && v != json!("");
            if truthy {
                return v;
            }
            if t.elapsed() > timeout {
                let _ = self.screenshot(&format!("FAILED-{}", slug(what))).await;
                let text = self
                    .js("return document.body.innerText.slice(0, 3000);", vec![])
                    .await;
                panic!(
                    "timed out after {timeout:?} waiting for {what} ({expr}); page text:\n{}",
                    text.as_str().unwrap_or("")
                );
            }
            tokio::time::sleep(Duration::from_millis(25)).await;
        }
    }

    pub async fn find(&self, css: &str) -> fantoccini::elements::Element {
        self.c
            .find(Locator::Css(css))
            .await
            .unwrap_or_else(|e| panic!("no element {css}: {e}"))
    }

    pub async fn exists(&self, css: &str) -> bool {
        !self
            .c
            .find_all(Locator::Css(css))
            .await
            .expect("find_all")
            .is_empty()
    }

    /// Clicks the element; when the page re-rendered it between finding and
    /// clicking (a live list redraws every refresh), finds it again (3 tries).
    pub async fn click(&self, css: &str) {
        for attempt in 1..=3 {
            match self.find(css).await.click().await {
                Ok(()) => return,
                Err(e) if attempt < 3 && e.to_string().contains("stale element") => {}
                Err(e) => panic!("click {css}: {e}"),
            }
        }
    }

    pub async fn type_into(&self, css: &str, text: &str) {
        self.find(css)
            .await
            .send_keys(text)
            .await
            .unwrap_or_else(|e| panic!("type into {css}: {e}"));
    }

    pub async fn text(&self, css: &str) -> String {
        self.find(css).await.text().await.expect("text")
    }

    /// Writes `name.png` into the artifacts directory.
    pub async fn screenshot(&self, name: &str) -> PathBuf {
        let png = self.c.screenshot().await.expect("screenshot");
        let p = artifacts_dir().join(format!("{name}.png"));
        std::fs::write(&p, png).expect("write screenshot");
        p
    }

    /// Writes `name.png` of one element (scrolled into view) into the artifacts directory.
    pub async fn screenshot_element(&self, css: &str, name: &str) -> PathBuf {
        let png = self
            .find(css)
            .await
            .screenshot()
            .await
            .unwrap_or_else(|e| panic!("screenshot of {css}: {e}"));
        let p = artifacts_dir().join(format!("{name}.png"));
        std::fs::write(&p, png).expect("write screenshot");
        p
    }

    /// Resizes the window so that the page's viewport is `w` x `h` CSS pixels,
    /// then waits two animation frames (layout and the plots' redraw).
    pub async fn set_viewport(&self, w: u32, h: u32) {
        for _ in 0..3 {
            let inner = self
                .js("return [window.innerWidth, window.innerHeight];", vec![])
                .await;
            let (iw, ih) = (
                inner[0].as_u64().unwrap_or(0) as i64,
                inner[1].as_u64().unwrap_or(0) as i64,
            );
            if (iw, ih) == (w as i64, h as i64) {
                break;
            }
            let (ow, oh) = self.c.get_window_size().await.expect("window size");
            let _ = self
                .c
                .set_window_size(
                    (ow as i64 + w as i64 - iw).max(100) as u32,
                    (oh as i64 + h as i64 - ih).max(100) as u32,
                )
                .await;
        }
        self.frames().await;
    }

    /// Waits until the page has drawn two animation frames (a resize observed).
    pub async fn frames(&self) {
        self.js(
            "return new Promise(r => requestAnimationFrame(() => requestAnimationFrame(() => setTimeout(() => r(true), 50))));",
            vec![],
        )
        .await;
    }

    /// Screenshots `name-1024x768.png`, `-1280x800` and `-1920x1080` (the
    /// station and office screens); the viewport is 1280x800 again after.
    pub async fn screenshot_sizes(&self, name: &str) {
        for (w, h) in [(1024, 768), (1920, 1080), (1280, 800)] {
            self.set_viewport(w, h).await;
            self.screenshot(&format!("{name}-{w}x{h}")).await;
            self.assert_nothing_overflows(&format!("{name} at {w}x{h}"))
                .await;
        }
    }

    /// No card, header or table cell of the page is wider than its box: a
    /// wider one is drawn past its border, clipped by the window or by a
    /// neighbour (the gauge table's AIAG column at 1024 px was). Scrolling
    /// containers (`overflow-x: auto`) are allowed to be wider inside.
    pub async fn assert_nothing_overflows(&self, at: &str) {
        let over = self
            .js(
                "const out = [];
                 for (const e of document.querySelectorAll('header, .card, .card > *, .report, .report > *, table.kv td, table.list td')) {
                   if (e.offsetParent === null && e.tagName !== 'HEADER') continue;
                   const cs = getComputedStyle(e);
                   if (cs.overflowX === 'auto' || cs.overflowX === 'scroll') continue;
                   if (e.scrollWidth > e.clientWidth + 1) {
                     out.push(`${e.tagName.toLowerCase()}${e.id ? '#' + e.id : ''}.${[...e.classList].join('.')} ${e.scrollWidth} > ${e.clientWidth} px: ${e.textContent.trim().slice(0, 60)}`);
                   }
                 }
                 // A visible input's placeholder (the only hint what to type)
                 // measured in the input's own font against its content box.
                 const ctx2d = document.createElement('canvas').getContext('2d');
                 for (const e of document.querySelectorAll('input[placeholder]')) {
                   if (e.offsetParent === null || !e.placeholder) continue;
                   const cs = getComputedStyle(e);
                   ctx2d.font = `${cs.fontStyle} ${cs.fontWeight} ${cs.fontSize} ${cs.fontFamily}`;
                   const text = ctx2d.measureText(e.placeholder).width;
                   const room = e.clientWidth - parseFloat(cs.paddingLeft) - parseFloat(cs.paddingRight);
                   if (text > room + 1) {
                     out.push(`input${e.id ? '#' + e.id : ''} placeholder ${Math.ceil(text)} > ${Math.floor(room)} px: ${e.placeholder}`);
                   }
                 }
                 return out;",
                vec![],
            )
            .await;
        let over = over.as_array().cloned().unwrap_or_default();
        assert!(over.is_empty(), "{at}: wider than its box: {over:#?}");
    }

    /// The page printed to PDF by Chromium (WebDriver print), on A4 or
    /// Letter (`letter`), portrait, with backgrounds and 1 cm margins.
    pub async fn print_pdf(&self, letter: bool) -> Vec<u8> {
        use fantoccini::wd::{PrintConfiguration, PrintMargins, PrintSize};
        let cfg = PrintConfiguration::builder()
            .size(if letter {
                PrintSize::US_LETTER
            } else {
                PrintSize::A4
            })
            .margins(PrintMargins {
                top: 1.0,
                bottom: 1.0,
                left: 1.0,
                right: 1.0,
            })
            .background(true)
            .build()
            .expect("print configuration");
        self.c.print(cfg).await.expect("print to PDF")
    }

    /// Signs in through the login form with `token`; waits for the role badge.
    pub async fn login(&mut self, base: &str, token: &str, role: &str) {
        self.goto(&format!("{base}/")).await;
        self.wait_js(
            "document.querySelector('#token')",
            Duration::from_secs(20),
            "the login form",
        )
        .await;
        self.type_into("#token", &format!("{token}\n")).await;
        self.wait_js(
            &format!("document.querySelector('#role') && document.querySelector('#role').textContent === '{role}'"),
            Duration::from_secs(20),
            "the role badge after login",
        )
        .await;
    }

    /// Ends the session (Chromium exits); Drop then stops chromedriver.
    pub async fn quit(self) {
        let _ = self.c.clone().close().await;
    }
}

impl Drop for Browser {
    fn drop(&mut self) {
        // The group of chromedriver (Chromium's processes are in it).
        // The shell's builtin kill: procps-ng 4.0.2's /usr/bin/kill sends a
        // negative (group) pid's signal to every process (pid -1).
        let _ = Command::new("bash")
            .arg("-c")
            .arg(format!("kill -s KILL -- -{}", self.driver.id()))
            .stderr(Stdio::null())
            .status();
        let _ = self.driver.wait();
    }
}

fn slug(s: &str) -> String {
    s.chars()
        .map(|c| if c.is_ascii_alphanumeric() { c } else { '-' })
        .collect::<String>()
        .chars()
        .take(60)
        .collect()
}

/// The number of pages of a PDF Chromium wrote: `/Count N` of the page
/// tree's root (the dictionary with `/Type /Pages` and no `/Parent`).
pub fn pdf_pages(pdf: &[u8]) -> usize {
    let text = String::from_utf8_lossy(pdf);
    let mut best = None;
    let mut from = 0;
    while let Some(i) = text[from..].find("/Pages") {
        let at = from + i;
        from = at + 6;
        let before = text[..at].trim_end();
        if !before.ends_with("/Type") {
            continue;
        }
        let (Some(open), Some(close)) = (text[..at].rfind("<<"), text[at..].find(">>")) else {
            continue;
        };
        let dict = &text[open..at + close];
        if dict.contains("/Parent") {
            continue;
        }
        if let Some(c) = dict.find("/Count") {
            let n: String = dict[c + 6..]
                .trim_start()
                .chars()
                .take_while(|c| c.is_ascii_digit())
                .collect();
            if let Ok(n) = n.parse::<usize>() {
                best = Some(n);
            }
        }
    }
    best.expect("a PDF page tree with /Count")
}
