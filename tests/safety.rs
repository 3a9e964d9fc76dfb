//! Never lose a user's work: the real `kin` binary killed while it writes, two `--apply` runs at
//! once, an edit saved while a diagnosis runs, a full disk, sixteen fits sharing one history, a
//! damaged history, an output naming an input, and `kin demo` in a folder that is not its own.
//! Each test checks the user's files byte for byte afterwards.

use std::collections::BTreeMap;
use std::path::{Path, PathBuf};
use std::process::{Child, Command, Output, Stdio};
use std::time::{Duration, Instant, SystemTime};

const KIN: &str = env!("CARGO_BIN_EXE_kin");
const ROOT: &str = env!("CARGO_MANIFEST_DIR");

fn kin(args: &[&str]) -> Output {
    Command::new(KIN)
        .args(args)
        .current_dir(ROOT)
        .output()
        .expect("kin runs")
}

fn spawn(args: &[&str]) -> Child {
    Command::new(KIN)
        .args(args)
        .current_dir(ROOT)
        .stdout(Stdio::null())
        .stderr(Stdio::null())
        .spawn()
        .expect("kin starts")
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

fn s(p: &Path) -> &str {
    p.to_str().expect("utf-8 path")
}

fn read(p: &Path) -> Vec<u8> {
    std::fs::read(p).unwrap_or_else(|e| panic!("{}: {e}", p.display()))
}

/// A small CMM whose data hide a backlash of Y that the model lacks: `kin diagnose` proposes
/// `Y.ty += backlash(Y)` (and two Abbe readings of it) as significant, with ~60 candidates in all.
const MODEL: &str = "machine cmm3 {
    task measure
    units { length mm, error um, tilt urad }
    axis X prismatic along x range 0 mm .. 800 mm
    axis Y prismatic along y range 0 mm .. 600 mm
    axis Z prismatic along z range -400 mm .. 0 mm
    tool chain {
        X moving
        Y moving
        Z moving at (0, 0, 500) mm
        tool probe at (0, 0, -100) mm
        tool side at (60, 40, -100) mm
    }
    errors {
        X.tx = spline(X, knots 2)
        X.rz = const
        Y.ty = linear(Y)
        Z.tz = linear(Z)
    }
}
";

/// Writes the model `cmm3.kin` and `points.csv` (`poses` poses simulated from the truth) in `dir`.
fn cmm3(dir: &Path, poses: usize) -> (PathBuf, PathBuf) {
    let model = dir.join("cmm3.kin");
    std::fs::write(&model, MODEL).unwrap();
    let truth = dir.join("truth.kin");
    std::fs::write(
        &truth,
        MODEL.replace(
            "        Y.ty = linear(Y)\n",
            "        Y.ty = linear(Y) + backlash(Y)\n",
        ),
    )
    .unwrap();
    let params = dir.join("truth.params");
    std::fs::write(
        &params,
        "params {\n    X.tx = [3, -2, 1, 0.5] um\n    X.rz[0] = 4 urad\n    Y.ty = [1.5, 0.5] um\n    Z.tz[0] = 2 um\n}\n",
    )
    .unwrap();
    let data = dir.join("points.csv");
    let n = poses.to_string();
    let out = kin(&[
        "simulate",
        s(&truth),
        "--params",
        s(&params),
        "--sample",
        &n,
        "--noise",
        "0.2um",
        "--seed",
        "3",
        "-o",
        s(&data),
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    (model, data)
}

/// Name → (length, modification time) of every entry of `dir`.
fn snapshot(dir: &Path) -> BTreeMap<String, (u64, Option<SystemTime>)> {
    std::fs::read_dir(dir)
        .map(|entries| {
            entries
                .flatten()
                .filter_map(|e| {
                    let m = e.metadata().ok()?;
                    Some((
                        e.file_name().to_string_lossy().into_owned(),
                        (m.len(), m.modified().ok()),
                    ))
                })
                .collect()
        })
        .unwrap_or_default()
}

/// Kills `child` as soon as `changed` says the folder changed (the write has begun), or after
/// `limit`; returns whether it was still running when killed.
fn kill_when(mut child: Child, limit: Duration, mut changed: impl FnMut() -> bool) -> bool {
    let start = Instant::now();
    loop {
        if let Ok(Some(_)) = child.try_wait() {
            return false;
        }
        if changed() || start.elapsed() >= limit {
            let running = matches!(child.try_wait(), Ok(None));
            let _ = child.kill();
            let _ = child.wait();
            return running;
        }
        std::thread::sleep(Duration::from_micros(200));
    }
}

/// Temporary files a killed writer left (`.NAME.XXXXXX.tmp`); removed, and counted.
fn sweep_temporaries(dir: &Path) -> usize {
    let mut n = 0;
    for e in std::fs::read_dir(dir).unwrap().flatten() {
        let name = e.file_name().to_string_lossy().into_owned();
        if name.starts_with('.') && name.ends_with(".tmp") {
            std::fs::remove_file(e.path()).unwrap();
            n += 1;
        }
    }
    n
}

/// `kin fit -o FIT.json` killed with SIGKILL at the moment its output folder first changes
/// (the write has begun) and at several fixed delays: FIT.json and FIT.params are each the old
/// complete text or the new complete text, never empty or cut.
#[test]
fn a_fit_killed_while_writing_leaves_old_or_new_files() {
    let dir = tempfile::tempdir().unwrap();
    let model = dir.path().join("bridge_cmm.kin");
    let data = dir.path().join("points.csv");
    std::fs::copy(Path::new(ROOT).join("examples/bridge_cmm.kin"), &model).unwrap();
    std::fs::copy(
        Path::new(ROOT).join("examples/data/bridge_cmm_points.csv"),
        &data,
    )
    .unwrap();
    // The new complete files, from an uninterrupted run in another folder.
    let reference = dir.path().join("reference");
    std::fs::create_dir(&reference).unwrap();
    let started = Instant::now();
    let out = kin(&[
        "fit",
        s(&model),
        s(&data),
        "-o",
        s(&reference.join("fit.json")),
    ]);
    let full = started.elapsed();
    assert!(out.status.success(), "{}", text(&out.stderr));
    let new_json = read(&reference.join("fit.json"));
    let new_params = read(&reference.join("fit.params"));
    assert!(new_json.len() > 100_000, "a write long enough to be hit");

    let out_dir = dir.path().join("out");
    std::fs::create_dir(&out_dir).unwrap();
    let (json, params) = (out_dir.join("fit.json"), out_dir.join("fit.params"));
    let (old_json, old_params) = (b"{\"old\": true}\n".to_vec(), b"params {}\n".to_vec());
    let delays = spread(full);
    let (mut killed, mut cut_short) = (0, 0);
    for delay in delays {
        std::fs::write(&json, &old_json).unwrap();
        std::fs::write(&params, &old_params).unwrap();
        let before = snapshot(&out_dir);
        let child = spawn(&["fit", s(&model), s(&data), "-o", s(&json)]);
        let limit = delay.unwrap_or(full * 4);
        let at_first_change = delay.is_none();
        if kill_when(child, limit, || {
            at_first_change && snapshot(&out_dir) != before
        }) {
            killed += 1;
        }
        let (j, p) = (read(&json), read(&params));
        assert!(
            j == old_json || j == new_json,
            "FIT.json cut ({} bytes) after a kill at {delay:?}",
            j.len()
        );
        assert!(
            p == old_params || p == new_params,
            "FIT.params cut ({} bytes) after a kill at {delay:?}",
            p.len()
        );
        cut_short += sweep_temporaries(&out_dir);
    }
    println!(
        "{killed} fits killed while running, {cut_short} of them in the middle of a write (a temporary file left)"
    );
    assert!(killed > 0, "no run was killed before it finished");
}

/// `kin diagnose --apply 1` killed as soon as the model or a temporary file next to it changes,
/// and at fixed delays: the model is the old text or the new text, never cut.
#[test]
fn an_apply_killed_while_writing_leaves_the_old_or_the_new_model() {
    let dir = tempfile::tempdir().unwrap();
    let (model, data) = cmm3(dir.path(), 600);
    // A long model (comments) makes the write long enough to be hit.
    let padding = "// a model with a long history of notes ............................\n";
    let start = format!("{}{MODEL}", padding.repeat(40_000));
    std::fs::write(&model, &start).unwrap();
    let reference = dir.path().join("reference");
    std::fs::create_dir(&reference).unwrap();
    let copy = reference.join("cmm3.kin");
    std::fs::copy(&model, &copy).unwrap();
    let started = Instant::now();
    let out = kin(&["diagnose", s(&copy), s(&data), "--apply", "1"]);
    let full = started.elapsed();
    assert!(out.status.success(), "{}", text(&out.stderr));
    let new = std::fs::read_to_string(&copy).unwrap();
    assert!(new.contains("Y.ty += backlash(Y)"), "{new}");

    let delays = spread(full);
    let (mut killed, mut cut_short) = (0, 0);
    for delay in delays {
        std::fs::write(&model, &start).unwrap();
        let before = std::fs::metadata(&model).unwrap().modified().unwrap();
        let child = spawn(&["diagnose", s(&model), s(&data), "--apply", "1"]);
        let at_first_change = delay.is_none();
        // The model itself changes, or a temporary file for it (not for `.previous`) appears.
        let writing = || {
            std::fs::metadata(&model)
                .ok()
                .and_then(|m| m.modified().ok())
                != Some(before)
                || snapshot(dir.path()).keys().any(|n| {
                    n.starts_with(".cmm3.kin.") && !n.contains("previous") && n.ends_with(".tmp")
                })
        };
        if kill_when(child, delay.unwrap_or(full * 4), || {
            at_first_change && writing()
        }) {
            killed += 1;
        }
        let now = std::fs::read_to_string(&model).unwrap();
        assert!(
            now == start || now == new,
            "model cut ({} bytes) after a kill at {delay:?}",
            now.len()
        );
        cut_short += sweep_temporaries(dir.path());
    }
    println!("{killed} runs killed while running, {cut_short} in the middle of a write");
    assert!(killed > 0, "no run was killed before it finished");
}

/// Two `--apply` runs on one model at once, several times: every run that says "added" has its
/// line in the file, the loser (if any) failed naming the change and wrote nothing, and the
/// final model checks clean.
#[test]
fn concurrent_applies_never_lose_an_added_line() {
    let dir = tempfile::tempdir().unwrap();
    let (model, data) = cmm3(dir.path(), 600);
    // The first-ranked line is the truth's; the second is whatever reading ranks next (an
    // Abbe-equivalent tilt, in one form or another): the test is about what is kept.
    let first = "Y.ty += backlash(Y)";
    let mut refused = 0;
    for _ in 0..4 {
        std::fs::write(&model, MODEL).unwrap();
        let runs: Vec<_> = ["1", "2"]
            .iter()
            .map(|n| {
                Command::new(KIN)
                    .args(["diagnose", s(&model), s(&data), "--apply", n])
                    .stdout(Stdio::piped())
                    .stderr(Stdio::piped())
                    .spawn()
                    .expect("kin starts")
            })
            .collect();
        let outs: Vec<Output> = runs
            .into_iter()
            .map(|c| c.wait_with_output().expect("kin ends"))
            .collect();
        let now = std::fs::read_to_string(&model).unwrap();
        for (n, out) in outs.iter().enumerate() {
            let said = text(&out.stdout);
            if out.status.success() {
                let prefix = format!("added to {}: ", s(&model));
                let line = said
                    .lines()
                    .find_map(|l| l.trim_start().strip_prefix(prefix.as_str()))
                    .unwrap_or_else(|| panic!("no added line in:\n{said}"));
                if n == 0 {
                    assert_eq!(line, first, "{said}");
                }
                assert!(
                    now.contains(&format!("        {line}\n")),
                    "{line} lost:\n{now}"
                );
            } else {
                refused += 1;
                assert_eq!(out.status.code(), Some(2), "{}", text(&out.stderr));
                assert!(
                    text(&out.stderr).contains("changed since this command read it"),
                    "{}",
                    text(&out.stderr)
                );
                assert!(!said.contains("added to"), "{said}");
            }
        }
        assert!(
            outs.iter().any(|o| o.status.success()),
            "one of two runs succeeds"
        );
        let check = kin(&["check", s(&model), "--no-identify"]);
        assert!(check.status.success(), "{}", text(&check.stderr));
    }
    println!("{refused} of 8 runs refused because the other had changed the model");
}

/// A line saved into the model while `kin diagnose --apply` fits is kept: the run refuses to
/// write (the edit came after its read), or — if the edit landed before it read the file — the
/// added line sits on top of the edit. Never is the edit reverted.
#[test]
fn an_edit_saved_during_apply_is_kept() {
    let dir = tempfile::tempdir().unwrap();
    let (model, data) = cmm3(dir.path(), 20_000);
    let child = Command::new(KIN)
        .args(["diagnose", s(&model), s(&data), "--apply", "1"])
        .stdout(Stdio::piped())
        .stderr(Stdio::piped())
        .spawn()
        .expect("kin starts");
    std::thread::sleep(Duration::from_millis(400));
    let edited = MODEL.replace("    task measure\n", "    task measure\n    // my note\n");
    std::fs::write(&model, &edited).unwrap();
    let out = child.wait_with_output().expect("kin ends");
    let now = std::fs::read_to_string(&model).unwrap();
    assert!(now.contains("// my note"), "the edit was reverted:\n{now}");
    if out.status.success() {
        println!("the edit landed before the model was read; the line was added on top of it");
        assert!(now.contains("Y.ty += backlash(Y)"), "{now}");
    } else {
        assert_eq!(out.status.code(), Some(2));
        assert!(
            text(&out.stderr).contains("changed since this command read it"),
            "{}",
            text(&out.stderr)
        );
        assert_eq!(now, edited);
    }
}

/// `--apply` of a candidate that is not significant changes nothing without `--force`;
/// `--dry-run` prints the lines and changes nothing; `--apply` keeps the previous text.
#[test]
fn apply_refuses_the_insignificant_and_dry_run_writes_nothing() {
    let dir = tempfile::tempdir().unwrap();
    let (model, data) = cmm3(dir.path(), 600);
    let out = kin(&[
        "diagnose",
        s(&model),
        s(&data),
        "-o",
        s(&dir.path().join("d.json")),
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let d: serde_json::Value = serde_json::from_slice(&read(&dir.path().join("d.json"))).unwrap();
    let findings = d["findings"].as_array().unwrap();
    let n = findings
        .iter()
        .position(|f| f["significant"] == false)
        .expect("an insignificant candidate")
        + 1;
    let n = n.to_string();
    let out = kin(&["diagnose", s(&model), s(&data), "--apply", &n]);
    assert_eq!(out.status.code(), Some(1), "{}", text(&out.stdout));
    assert!(
        text(&out.stderr).contains("not significant"),
        "{}",
        text(&out.stderr)
    );
    assert_eq!(std::fs::read_to_string(&model).unwrap(), MODEL);

    let out = kin(&["diagnose", s(&model), s(&data), "--apply", "1", "--dry-run"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(
        text(&out.stdout).contains("+         Y.ty += backlash(Y)"),
        "{}",
        text(&out.stdout)
    );
    assert_eq!(std::fs::read_to_string(&model).unwrap(), MODEL);
    assert!(!dir.path().join("cmm3.kin.previous").exists());

    let out = kin(&["diagnose", s(&model), s(&data), "--apply", &n, "--force"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert_ne!(std::fs::read_to_string(&model).unwrap(), MODEL);
    assert_eq!(
        std::fs::read_to_string(dir.path().join("cmm3.kin.previous")).unwrap(),
        MODEL
    );
    // The replaced revision's text is in its history record too.
    let history = std::fs::read_to_string(dir.path().join("cmm3.kin.history.jsonl")).unwrap();
    let kept = history
        .lines()
        .filter_map(|l| serde_json::from_str::<serde_json::Value>(l).ok())
        .any(|e| e["source"] == MODEL);
    assert!(kept, "{history}");
}

/// Unmounts on drop, so a failing test does not leave a mount behind.
struct Mount(PathBuf);

impl Drop for Mount {
    fn drop(&mut self) {
        let _ = Command::new("umount").arg(&self.0).status();
    }
}

/// A 64 KiB tmpfs, or `None` (with the reason printed) where mounting is not allowed.
fn tiny_disk(dir: &Path) -> Option<Mount> {
    let at = dir.join("disk");
    std::fs::create_dir(&at).unwrap();
    let mounted = Command::new("mount")
        .args(["-t", "tmpfs", "-o", "size=64k", "tmpfs", s(&at)])
        .stderr(Stdio::null())
        .status()
        .map(|st| st.success())
        .unwrap_or(false);
    if mounted {
        Some(Mount(at))
    } else {
        println!("skipped: cannot mount a tmpfs here (not root, or no mount)");
        None
    }
}

/// Fills the file system holding `dir` to the last byte.
fn fill(dir: &Path) {
    use std::io::Write;
    let mut f = std::fs::File::create(dir.join("filler")).unwrap();
    let block = [0u8; 4096];
    while f.write_all(&block).is_ok() {}
    let _ = f.write_all(&[0u8]);
}

/// A full disk: the FIT.json already there and the model under `--apply` survive whole, the
/// error says what could not be written (exit 2), and no temporary file is left.
#[test]
fn a_full_disk_leaves_the_old_files_whole() {
    let dir = tempfile::tempdir().unwrap();
    let Some(disk) = tiny_disk(dir.path()) else {
        return;
    };
    let (model, data) = cmm3(dir.path(), 600);
    let json = disk.0.join("fit.json");
    std::fs::write(&json, b"{\"old\": true}\n").unwrap();
    let out = kin(&["fit", s(&model), s(&data), "-o", s(&json)]);
    assert_eq!(out.status.code(), Some(2), "{}", text(&out.stdout));
    assert!(
        text(&out.stderr).contains("cannot write"),
        "{}",
        text(&out.stderr)
    );
    assert_eq!(read(&json), b"{\"old\": true}\n");
    assert_eq!(sweep_temporaries(&disk.0), 0, "a temporary file was left");

    let on_disk = disk.0.join("cmm3.kin");
    std::fs::write(&on_disk, MODEL).unwrap();
    fill(&disk.0);
    let out = kin(&["diagnose", s(&on_disk), s(&data), "--apply", "1"]);
    assert_eq!(out.status.code(), Some(2), "{}", text(&out.stdout));
    assert!(
        text(&out.stderr).contains("cannot write"),
        "{}",
        text(&out.stderr)
    );
    assert_eq!(std::fs::read_to_string(&on_disk).unwrap(), MODEL);
    assert_eq!(sweep_temporaries(&disk.0), 0, "a temporary file was left");
}

/// Sixteen fits of one model at once: sixteen complete history records.
#[test]
fn sixteen_concurrent_fits_leave_sixteen_records() {
    let dir = tempfile::tempdir().unwrap();
    let (model, data) = cmm3(dir.path(), 300);
    let runs: Vec<Child> = (0..16)
        .map(|_| {
            Command::new(KIN)
                .args(["fit", s(&model), s(&data)])
                .stdout(Stdio::null())
                .stderr(Stdio::piped())
                .spawn()
                .expect("kin starts")
        })
        .collect();
    for r in runs {
        let out = r.wait_with_output().expect("kin ends");
        assert!(out.status.success(), "{}", text(&out.stderr));
        assert!(
            !text(&out.stderr).contains("warning"),
            "{}",
            text(&out.stderr)
        );
    }
    let history = std::fs::read_to_string(dir.path().join("cmm3.kin.history.jsonl")).unwrap();
    let records: Vec<serde_json::Value> = history
        .lines()
        .map(|l| serde_json::from_str(l).unwrap_or_else(|e| panic!("{e}: {l}")))
        .collect();
    assert_eq!(records.len(), 16, "{history}");
    assert!(records.iter().all(|r| r["sigma"].is_f64()));
}

/// A history with a damaged line and a record whose σ̂ was not finite (`null`): the fit warns
/// once naming the damaged line only, keeps every other record, and `kin report` still shows
/// the history.
#[test]
fn a_damaged_history_is_read_around() {
    let dir = tempfile::tempdir().unwrap();
    let (model, data) = cmm3(dir.path(), 300);
    let json = dir.path().join("fit.json");
    let out = kin(&["fit", s(&model), s(&data), "-o", s(&json)]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let history = dir.path().join("cmm3.kin.history.jsonl");
    let good = std::fs::read_to_string(&history).unwrap();
    let good = good.trim_end();
    let null_sigma = good
        .replacen("\"sigma\":", "\"sigma\":null,\"was\":", 1)
        .replacen("\"rms\":", "\"rms\":null,\"was_rms\":", 1);
    assert!(null_sigma.contains("\"sigma\":null"), "{null_sigma}");
    std::fs::write(
        &history,
        format!("{good}\n{{\"time\": 17, \"model_ha\n{null_sigma}\n"),
    )
    .unwrap();
    let out = kin(&["fit", s(&model), s(&data)]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let err = text(&out.stderr);
    assert_eq!(err.matches("warning").count(), 1, "{err}");
    assert!(
        err.contains("line 2 is not") && err.contains("other 2 entries are kept"),
        "{err}"
    );
    let lines = std::fs::read_to_string(&history).unwrap();
    assert_eq!(lines.lines().count(), 4, "{lines}");

    let html = dir.path().join("report.html");
    let out = kin(&[
        "report",
        s(&model),
        "--fit",
        s(&json),
        s(&data),
        "-o",
        s(&html),
    ]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let page = std::fs::read_to_string(&html).unwrap();
    assert!(!page.contains("No history yet"), "the history was lost");
    assert!(
        page.contains("line 2 is not"),
        "the report says which line was skipped"
    );
    // `--apply` reads the history twice (before and after the change): one warning.
    let out = kin(&["diagnose", s(&model), s(&data), "--apply", "1"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert_eq!(
        text(&out.stderr).matches("warning").count(),
        1,
        "{}",
        text(&out.stderr)
    );
}

/// `-o` naming an input (under another spelling too) or a folder that does not exist is
/// refused at once with exit 2; every input stays byte-identical and nothing is fitted.
#[test]
fn an_output_naming_an_input_is_refused() {
    let dir = tempfile::tempdir().unwrap();
    let (model, data) = cmm3(dir.path(), 100);
    let params = dir.path().join("truth.params");
    let json = dir.path().join("fit.json");
    let out = kin(&["fit", s(&model), s(&data), "-o", s(&json)]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let history = dir.path().join("cmm3.kin.history.jsonl");
    let files = [&model, &data, &params, &json, &history];
    let before: Vec<Vec<u8>> = files.iter().map(|p| read(p)).collect();
    let respelled = dir.path().join(".").join("points.csv");
    let d = s(dir.path());
    let cases: Vec<Vec<String>> = vec![
        vec![
            "fit".into(),
            s(&model).into(),
            s(&data).into(),
            "-o".into(),
            s(&model).into(),
        ],
        vec![
            "fit".into(),
            s(&model).into(),
            s(&data).into(),
            "-o".into(),
            s(&respelled).into(),
        ],
        vec![
            "fit".into(),
            s(&model).into(),
            s(&data).into(),
            "-o".into(),
            format!("{d}/no/such/fit.json"),
        ],
        vec![
            "diagnose".into(),
            s(&model).into(),
            s(&data).into(),
            "-o".into(),
            s(&data).into(),
        ],
        vec![
            "diagnose".into(),
            s(&model).into(),
            s(&data).into(),
            "-o".into(),
            s(&history).into(),
        ],
        vec![
            "report".into(),
            s(&model).into(),
            "--fit".into(),
            s(&json).into(),
            "-o".into(),
            s(&json).into(),
        ],
        // The data FIT.json names, read when none are given.
        vec![
            "report".into(),
            s(&model).into(),
            "--fit".into(),
            s(&json).into(),
            "-o".into(),
            s(&data).into(),
        ],
        vec![
            "simulate".into(),
            s(&model).into(),
            "--sample".into(),
            "5".into(),
            "--params".into(),
            s(&params).into(),
            "-o".into(),
            s(&params).into(),
        ],
        vec![
            "eval".into(),
            s(&model).into(),
            s(&data).into(),
            "-o".into(),
            s(&data).into(),
        ],
    ];
    for args in cases {
        let args: Vec<&str> = args.iter().map(String::as_str).collect();
        let out = kin(&args);
        assert_eq!(
            out.status.code(),
            Some(2),
            "{args:?}: {}",
            text(&out.stdout)
        );
        let err = text(&out.stderr);
        assert!(
            err.contains("is also an input") || err.contains("does not exist"),
            "{args:?}: {err}"
        );
        assert!(
            text(&out.stdout).is_empty(),
            "{args:?} did work before refusing"
        );
        let after: Vec<Vec<u8>> = files.iter().map(|p| read(p)).collect();
        assert!(after == before, "{args:?} changed an input");
    }
}

/// `kin demo --dir D` writes into a folder of its own only: a second run over its own output
/// works, a folder holding a user's file of one of its names is refused (exit 2), untouched.
#[test]
fn demo_writes_only_into_its_own_folder() {
    let dir = tempfile::tempdir().unwrap();
    let own = dir.path().join("own");
    for _ in 0..2 {
        let out = kin(&["demo", "--dir", s(&own), "--rounds", "0"]);
        assert!(out.status.success(), "{}", text(&out.stderr));
    }
    for name in [
        "bridge_cmm.kin",
        "points.csv",
        "bridge_cmm.kin.history.jsonl",
        "report.html",
    ] {
        let user = dir.path().join(format!("user-{name}"));
        std::fs::create_dir(&user).unwrap();
        std::fs::write(user.join(name), "the user's own work\n").unwrap();
        let out = kin(&["demo", "--dir", s(&user), "--rounds", "0"]);
        assert_eq!(out.status.code(), Some(2), "{name}: {}", text(&out.stdout));
        assert!(
            text(&out.stderr).contains("was not written by `kin demo`"),
            "{}",
            text(&out.stderr)
        );
        assert_eq!(
            std::fs::read_to_string(user.join(name)).unwrap(),
            "the user's own work\n"
        );
        assert_eq!(
            std::fs::read_dir(&user).unwrap().count(),
            1,
            "{name}: files added"
        );
    }
}

/// Runs `args` `delays.len()` times from `reset`, killing each run as soon as `changed` says its
/// output began to change (a `None` delay) or at the delay, and after each kill asks `whole`
/// whether what is on disk is the old result or the new one; returns how many runs were
/// killed while still running.
fn kill_runs(
    args: &[&str],
    delays: &[Option<Duration>],
    full: Duration,
    mut reset: impl FnMut(),
    mut changed: impl FnMut() -> bool,
    mut whole: impl FnMut(Option<Duration>),
) -> usize {
    let mut killed = 0;
    for &delay in delays {
        reset();
        let child = spawn(args);
        let limit = delay.unwrap_or(full * 4);
        let first_change = delay.is_none();
        if kill_when(child, limit, || first_change && changed()) {
            killed += 1;
        }
        whole(delay);
    }
    killed
}

/// 25 kills: a few at the first change of the output, the rest spread over the run (four
/// commands, 100 runs in all).
fn spread(full: Duration) -> Vec<Option<Duration>> {
    let mut delays: Vec<Option<Duration>> = vec![None; 5];
    delays.extend((0..20).map(|k| Some(full.mul_f64(0.06 * k as f64))));
    delays
}

/// `kin compensate --table` killed 25 times at the first change of its folder and at delays
/// over the run: the folder always holds one whole set — the old tables and note, or the new
/// ones — never a new table beside an old one, and no earlier set's file left behind it.
#[test]
fn a_table_set_killed_while_written_is_the_old_set_or_the_new() {
    let dir = tempfile::tempdir().unwrap();
    let (model, data) = cmm3(dir.path(), 200);
    let position = dir.path().join("mill3.kin");
    std::fs::write(
        &position,
        std::fs::read_to_string(&model)
            .unwrap()
            .replace("task measure", "task position"),
    )
    .unwrap();
    let fit = dir.path().join("fit.json");
    let out = kin(&["fit", s(&position), s(&data), "-o", s(&fit)]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    let tables = dir.path().join("tables");
    let run = |grid: &str| {
        vec![
            "compensate".to_string(),
            s(&position).to_string(),
            "--fit".into(),
            s(&fit).to_string(),
            "--grid".into(),
            grid.to_string(),
            "--table".into(),
            "linuxcnc".into(),
            "-o".into(),
            s(&tables).to_string(),
        ]
    };
    // The old set over X and Y, the new over X alone (its Y.comp must go).
    let old_grid = "X=0:800:4,Y=0:600:200,Z=-100";
    let new_grid = "X=0:800:5,Y=300,Z=-100";
    let contents = |d: &Path| -> BTreeMap<String, Vec<u8>> {
        std::fs::read_dir(d)
            .map(|entries| {
                entries
                    .flatten()
                    .filter(|e| !e.file_name().to_string_lossy().starts_with('.'))
                    // Read while the run may still be exchanging the folders (the check
                    // for its first change): an entry may vanish between listing and reading.
                    .filter_map(|e| {
                        let bytes = std::fs::read(e.path()).ok()?;
                        Some((e.file_name().to_string_lossy().into_owned(), bytes))
                    })
                    .collect()
            })
            .unwrap_or_default()
    };
    let old_args = run(old_grid);
    let old_args: Vec<&str> = old_args.iter().map(String::as_str).collect();
    assert!(kin(&old_args).status.success());
    let old = contents(&tables);
    let new_args = run(new_grid);
    let new_args: Vec<&str> = new_args.iter().map(String::as_str).collect();
    let started = Instant::now();
    assert!(kin(&new_args).status.success());
    let full = started.elapsed();
    let new = contents(&tables);
    assert!(old.contains_key("Y.comp") && !new.contains_key("Y.comp"));
    let killed = kill_runs(
        &new_args,
        &spread(full),
        full,
        || {
            let _ = std::fs::remove_dir_all(&tables);
            for e in std::fs::read_dir(dir.path()).unwrap().flatten() {
                // A fresh folder a killed run left beside `tables`.
                if e.file_name().to_string_lossy().starts_with(".tables") {
                    let _ = std::fs::remove_dir_all(e.path());
                }
            }
            assert!(kin(&old_args).status.success());
        },
        || contents(&tables) != old,
        |delay| {
            let now = contents(&tables);
            assert!(
                now == old || now == new,
                "after a kill at {delay:?} the folder holds {:?}",
                now.keys().collect::<Vec<_>>()
            );
        },
    );
    println!("{killed} of 25 table runs killed while running");
    assert!(killed > 0, "no run was killed before it finished");
}

/// `kin fmt` in place killed 25 times: the file is the old text or the formatted one, never
/// cut.
#[test]
fn a_format_in_place_killed_is_the_old_file_or_the_new() {
    let dir = tempfile::tempdir().unwrap();
    let file = dir.path().join("long.kin");
    // A model long enough (its comments) for the write to be hit, badly laid out.
    let messy = MODEL.replace("    ", "  ")
        + &"//   a note with   spaces  .............................................\n"
            .repeat(40_000);
    std::fs::write(&file, &messy).unwrap();
    let started = Instant::now();
    assert!(kin(&["fmt", s(&file)]).status.success());
    let full = started.elapsed();
    let formatted = read(&file);
    assert_ne!(formatted, messy.as_bytes(), "fmt changed nothing");
    let killed = kill_runs(
        &["fmt", s(&file)],
        &spread(full),
        full,
        || std::fs::write(&file, &messy).unwrap(),
        || std::fs::metadata(&file).map(|m| m.len()).ok() != Some(messy.len() as u64),
        |delay| {
            let now = read(&file);
            assert!(
                now == messy.as_bytes() || now == formatted,
                "{} bytes after a kill at {delay:?}",
                now.len()
            );
            sweep_temporaries(dir.path());
        },
    );
    println!("{killed} of 25 fmt runs killed while running");
    assert!(killed > 0, "no run was killed before it finished");
}
