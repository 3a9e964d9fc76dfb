//! What several end-to-end test files share: running the real binary, scratch folders, and the
//! small three-axis CMM model most of them simulate and fit.

#![allow(dead_code)]

use std::path::PathBuf;
use std::process::{Command, Output};

/// Runs `kin` with `args` from the crate's root.
pub fn kin(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_kin"))
        .args(args)
        .current_dir(env!("CARGO_MANIFEST_DIR"))
        .output()
        .expect("kin runs")
}

/// A fresh folder for one test, inside this process's scratch folder.
pub fn scratch(test: &str) -> PathBuf {
    let dir = std::env::temp_dir()
        .join(format!(
            "kin-{}-{}",
            env!("CARGO_CRATE_NAME"),
            std::process::id()
        ))
        .join(test);
    let _ = std::fs::remove_dir_all(&dir);
    std::fs::create_dir_all(&dir).expect("scratch folder");
    dir
}

pub fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// Standard output, after checking that `kin` succeeded.
pub fn ok(out: &Output) -> String {
    assert!(
        out.status.success(),
        "exit {:?}\n{}\n{}",
        out.status.code(),
        text(&out.stdout),
        text(&out.stderr)
    );
    text(&out.stdout)
}

/// A bridge-like CMM with three prismatic axes and a small error model: a spline, a constant
/// rotation and two linear terms (`ERRORS` is its `errors` block's body).
pub fn cmm3(errors: &str) -> String {
    format!(
        "machine cmm3 {{
    task measure
    units {{ length mm, error um, tilt urad }}
    axis X prismatic along x range 0 mm .. 800 mm
    axis Y prismatic along y range 0 mm .. 600 mm
    axis Z prismatic along z range -400 mm .. 0 mm
    tool chain {{
        X moving
        Y moving
        Z moving at (0, 0, 500) mm
        tool probe at (0, 0, -100) mm
    }}
    errors {{
{errors}    }}
}}
"
    )
}

/// The body of `cmm3`'s usual `errors` block.
pub const CMM3_ERRORS: &str = "        X.tx = spline(X, knots 2)
        X.rz = const
        Y.ty = linear(Y)
        Z.tz = linear(Z)
";

/// Values for `CMM3_ERRORS`, as a `params` block.
pub const CMM3_TRUTH: &str = "params {
    X.tx = [3, -2, 1, 0.5] um
    X.rz[0] = 4 urad
    Y.ty[0] = 1.5 um
    Z.tz[0] = 2 um
}
";

/// Simulates `n` poses of `model` at `params` with `extra` options into `out`.
pub fn simulate(model: &str, params: &str, n: usize, seed: u64, extra: &[&str], out: &str) {
    let n = n.to_string();
    let seed = seed.to_string();
    let mut args = vec![
        "simulate", model, "--params", params, "--sample", &n, "--seed", &seed, "-o", out,
    ];
    args.extend_from_slice(extra);
    ok(&kin(&args));
}

/// A Chromium to render with: `/usr/bin/chromium`, or one of the usual names on `PATH`.
pub fn browser() -> Option<PathBuf> {
    let fixed = PathBuf::from("/usr/bin/chromium");
    if fixed.is_file() {
        return Some(fixed);
    }
    let path = std::env::var_os("PATH")?;
    [
        "chromium",
        "chromium-browser",
        "google-chrome",
        "google-chrome-stable",
    ]
    .iter()
    .flat_map(|name| std::env::split_paths(&path).map(move |d| d.join(name)))
    .find(|p| p.is_file())
}

/// Renders `page` headless at 1280 × `height` and checks the screenshot is a real picture of
/// it (a PNG of that size, larger than `min_bytes`: a blank or error page compresses to a few
/// kB). Skipped, saying so, without a browser. `KIN_SCREENSHOT_DIR` keeps the picture.
pub fn screenshot(page: &std::path::Path, dir: &std::path::Path, height: u32, min_bytes: usize) {
    use std::process::Stdio;
    use std::time::{Duration, Instant};
    let Some(chromium) = browser() else {
        println!("browser check skipped: no chromium at /usr/bin/chromium or on PATH");
        return;
    };
    let name = page
        .file_stem()
        .map_or("page".into(), |s| s.to_string_lossy().to_string());
    let png = dir.join(format!("{name}.png"));
    let profile = dir.join("chromium-profile");
    let page = page.canonicalize().expect("page path");
    let mut child = Command::new(&chromium)
        .args([
            "--headless",
            "--no-sandbox",
            "--disable-gpu",
            "--disable-quic",
            "--no-first-run",
            "--disable-background-networking",
            "--disable-component-update",
            "--disable-sync",
            "--hide-scrollbars",
            &format!("--user-data-dir={}", profile.display()),
            &format!("--screenshot={}", png.display()),
            &format!("--window-size=1280,{height}"),
            &format!("file://{}", page.display()),
        ])
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("chromium starts");
    // A browser that hangs must not hang the test suite.
    let start = Instant::now();
    loop {
        match child.try_wait().expect("wait for chromium") {
            Some(_) => break,
            None if start.elapsed() > Duration::from_secs(180) => {
                let _ = child.kill();
                let _ = child.wait();
                panic!(
                    "{} did not finish the screenshot in 180 s",
                    chromium.display()
                );
            }
            None => std::thread::sleep(Duration::from_millis(100)),
        }
    }
    let bytes = std::fs::read(&png)
        .unwrap_or_else(|e| panic!("no screenshot from {}: {e}", chromium.display()));
    assert!(bytes.starts_with(b"\x89PNG\r\n\x1a\n"), "not a PNG");
    // IHDR: width and height, big-endian, right after the signature and chunk header.
    let dim =
        |at: usize| u32::from_be_bytes([bytes[at], bytes[at + 1], bytes[at + 2], bytes[at + 3]]);
    assert_eq!((dim(16), dim(20)), (1280, height));
    assert!(
        bytes.len() > min_bytes,
        "screenshot is only {} bytes",
        bytes.len()
    );
    println!(
        "browser check: {} rendered {}, screenshot {} ({} bytes)",
        chromium.display(),
        page.display(),
        png.display(),
        bytes.len()
    );
    if let Some(keep) = std::env::var_os("KIN_SCREENSHOT_DIR") {
        let _ = std::fs::create_dir_all(&keep);
        std::fs::copy(
            &png,
            std::path::Path::new(&keep).join(png.file_name().unwrap_or_default()),
        )
        .expect("keep the screenshot");
    }
}

/// Runs the browser with `args` and returns its standard output; a browser that hangs must not
/// hang the test suite (killed after 180 s).
pub fn run_browser(chromium: &std::path::Path, args: &[&str]) -> Vec<u8> {
    use std::io::Read as _;
    use std::process::Stdio;
    let mut child = Command::new(chromium)
        .args(args)
        .stdout(Stdio::piped())
        .stderr(Stdio::null())
        .spawn()
        .expect("chromium starts");
    let mut stdout = child.stdout.take().expect("stdout");
    let reader = std::thread::spawn(move || {
        let mut out = Vec::new();
        let _ = stdout.read_to_end(&mut out);
        out
    });
    let start = std::time::Instant::now();
    loop {
        match child.try_wait().expect("wait for chromium") {
            Some(_) => break,
            None if start.elapsed() > std::time::Duration::from_secs(180) => {
                let _ = child.kill();
                let _ = child.wait();
                panic!("{} did not finish in 180 s", chromium.display());
            }
            None => std::thread::sleep(std::time::Duration::from_millis(100)),
        }
    }
    reader.join().expect("reader")
}
