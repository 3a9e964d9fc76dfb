//! What the shell and `man` know of `kin`: completion scripts and manual pages, both generated
//! from the same clap definition as `--help`, so they cannot drift from the command line.

use std::io::Write;
use std::path::Path;
use std::process::ExitCode;

use crate::load::Failed;

/// Prints the completion script of `shell` for `cli` on standard output.
pub fn completions(mut cli: clap::Command, shell: clap_complete::Shell) -> ExitCode {
    let mut out = Vec::new();
    clap_complete::generate(shell, &mut cli, "kin", &mut out);
    Failed::exit(print(&out))
}

/// `kin.1` on standard output, or every page (`kin.1`, `kin-fit.1`, …) into the folder `dir`,
/// each replaced atomically.
pub fn man(cli: clap::Command, dir: Option<&Path>) -> ExitCode {
    Failed::exit(match dir {
        None => render(&cli).and_then(|page| print(&page)),
        Some(dir) => pages(cli, dir),
    })
}

fn pages(cli: clap::Command, dir: &Path) -> Result<(), Failed> {
    if !dir.is_dir() {
        eprintln!("error: `{}` is not a folder", dir.display());
        return Err(Failed::USAGE);
    }
    let cli = cli.name("kin");
    let mut written = vec![("kin.1".to_string(), render(&cli)?)];
    for sub in cli.get_subcommands().filter(|s| s.get_name() != "help") {
        // The page of `kin fit` is named `kin-fit` and shows `kin fit` in its synopsis.
        let name = format!("kin-{}", sub.get_name());
        let page = sub
            .clone()
            .name(name.clone())
            .bin_name(format!("kin {}", sub.get_name()));
        written.push((format!("{name}.1"), render(&page)?));
        // A command of commands (`kin import urdf`): a page for each, `kin-import-urdf`.
        for inner in sub.get_subcommands().filter(|s| s.get_name() != "help") {
            let inner_name = format!("{name}-{}", inner.get_name());
            let page = inner.clone().name(inner_name.clone()).bin_name(format!(
                "kin {} {}",
                sub.get_name(),
                inner.get_name()
            ));
            written.push((format!("{inner_name}.1"), render(&page)?));
        }
    }
    for (file, page) in &written {
        let path = dir.join(file);
        crate::files::check(&path, &[])?;
        crate::files::write(&path, page)?;
    }
    eprintln!(
        "wrote {} manual pages into {}",
        written.len(),
        dir.display()
    );
    Ok(())
}

fn render(cli: &clap::Command) -> Result<Vec<u8>, Failed> {
    let mut page = Vec::new();
    clap_mangen::Man::new(cli.clone())
        .render(&mut page)
        .map_err(|e| {
            eprintln!("error: cannot render the manual page: {e}");
            Failed::USAGE
        })?;
    Ok(page)
}

fn print(bytes: &[u8]) -> Result<(), Failed> {
    let mut stdout = std::io::stdout().lock();
    stdout
        .write_all(bytes)
        .and_then(|()| stdout.flush())
        .map_err(|e| {
            eprintln!("error: cannot write to standard output: {e}");
            Failed::USAGE
        })
}
