//! `kin init`: every template it writes checks clean (no error, no warning) and is formatted;
//! it lists them; it never writes over a file.

use std::path::{Path, PathBuf};
use std::process::{Command, Output};

fn kin(args: &[&str]) -> Output {
    Command::new(env!("CARGO_BIN_EXE_kin"))
        .args(args)
        .env("NO_COLOR", "1")
        .output()
        .expect("kin runs")
}

fn text(bytes: &[u8]) -> String {
    String::from_utf8_lossy(bytes).into_owned()
}

/// The template names `kin init --list` prints, one a line after the heading.
fn listed() -> Vec<String> {
    let out = kin(&["init", "--list"]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    text(&out.stdout)
        .lines()
        .skip(1)
        .filter_map(|l| l.split_whitespace().next().map(str::to_string))
        .collect()
}

fn path_str(p: &Path) -> &str {
    p.to_str().expect("a UTF-8 temporary path")
}

#[test]
fn the_list_names_every_template_once_with_a_line_each() {
    let names = listed();
    assert_eq!(
        names,
        ["bridge-cmm", "mill-3axis", "mill-5axis", "arm-6axis"],
        "{names:?}"
    );
    // `kin init` alone prints the same list.
    let bare = kin(&["init"]);
    assert!(bare.status.success());
    assert_eq!(text(&bare.stdout), text(&kin(&["init", "--list"]).stdout));
    // Every template file in src/init is offered, and written as it is.
    let dir = PathBuf::from(env!("CARGO_MANIFEST_DIR")).join("src/init");
    let mut files: Vec<String> = std::fs::read_dir(&dir)
        .expect("src/init")
        .filter_map(|e| e.ok().map(|e| e.path()))
        .filter(|p| p.extension().is_some_and(|x| x == "kin"))
        .filter_map(|p| p.file_stem().and_then(|s| s.to_str()).map(str::to_string))
        .collect();
    files.sort();
    let mut offered: Vec<String> = names.iter().map(|n| n.replace('-', "_")).collect();
    offered.sort();
    assert_eq!(files, offered);
}

#[test]
fn every_template_checks_clean_and_is_formatted() {
    let tmp = tempfile::tempdir().expect("temporary folder");
    for name in listed() {
        let dir = tmp.path().join(&name);
        let out = kin(&["init", &name, path_str(&dir)]);
        assert!(out.status.success(), "{name}: {}", text(&out.stderr));
        let model = dir.join("machine.kin");
        let source = std::fs::read_to_string(&model).expect("machine.kin written");
        let file = format!(
            "{}/src/init/{}.kin",
            env!("CARGO_MANIFEST_DIR"),
            name.replace('-', "_")
        );
        assert_eq!(
            source,
            std::fs::read_to_string(file).expect("template file")
        );

        let check = kin(&["check", path_str(&model)]);
        assert!(
            check.status.success() && check.stderr.is_empty(),
            "{name}: `kin check` is not clean:\n{}{}",
            text(&check.stdout),
            text(&check.stderr)
        );
        assert!(text(&check.stdout).contains("checks clean"));
        let fmt = kin(&["fmt", "--check", path_str(&model)]);
        assert!(fmt.status.success(), "{name}: {}", text(&fmt.stderr));
    }
    // The CMM's comment promises that its styli make it identifiable from positions alone.
    let cmm = tmp.path().join("bridge-cmm/machine.kin");
    let check = kin(&["check", path_str(&cmm), "--observe", "position"]);
    assert!(check.status.success(), "{}", text(&check.stderr));
}

#[test]
fn an_existing_file_is_never_written_over() {
    let tmp = tempfile::tempdir().expect("temporary folder");
    let dir = tmp.path().join("mill");
    assert!(kin(&["init", "mill-3axis", path_str(&dir)])
        .status
        .success());
    let model = dir.join("machine.kin");
    std::fs::write(&model, "// my edited model\n").expect("edit");
    let again = kin(&["init", "bridge-cmm", path_str(&dir)]);
    assert_eq!(again.status.code(), Some(2));
    assert!(
        text(&again.stderr).contains("exists already"),
        "{}",
        text(&again.stderr)
    );
    assert_eq!(
        std::fs::read_to_string(&model).expect("model"),
        "// my edited model\n"
    );
    // Nothing else was left in the folder (no temporary file).
    assert_eq!(std::fs::read_dir(&dir).expect("folder").count(), 1);

    // A symbolic link in its place is not followed, even dangling.
    #[cfg(unix)]
    {
        let linked = tmp.path().join("linked");
        std::fs::create_dir(&linked).expect("folder");
        std::os::unix::fs::symlink(tmp.path().join("nowhere.kin"), linked.join("machine.kin"))
            .expect("link");
        let out = kin(&["init", "mill-3axis", path_str(&linked)]);
        assert_eq!(out.status.code(), Some(2));
        assert!(!tmp.path().join("nowhere.kin").exists());
    }

    // DIR a file, or an unknown template: usage errors, nothing written.
    let file = tmp.path().join("plain");
    std::fs::write(&file, "x").expect("file");
    let out = kin(&["init", "mill-3axis", path_str(&file)]);
    assert_eq!(out.status.code(), Some(2), "{}", text(&out.stderr));
    let out = kin(&["init", "lathe", path_str(&tmp.path().join("lathe"))]);
    assert_eq!(out.status.code(), Some(2));
    assert!(!tmp.path().join("lathe").exists());
}

#[test]
fn the_folder_is_created_and_the_default_is_the_current_one() {
    let tmp = tempfile::tempdir().expect("temporary folder");
    let nested = tmp.path().join("a/b");
    let out = kin(&["init", "arm-6axis", path_str(&nested)]);
    assert!(out.status.success(), "{}", text(&out.stderr));
    assert!(nested.join("machine.kin").is_file());
    let here = Command::new(env!("CARGO_BIN_EXE_kin"))
        .args(["init", "mill-5axis"])
        .current_dir(tmp.path())
        .output()
        .expect("kin runs");
    assert!(here.status.success(), "{}", text(&here.stderr));
    assert!(tmp.path().join("machine.kin").is_file());
    assert!(text(&here.stdout).starts_with("wrote machine.kin: a 5-axis"));
}
