//! Help for the arguments many commands share (`MACHINE`, `--color`, `--engine`, `--format`,
//! …), written once here instead of repeated on every command: the definition in `main.rs`
//! documents what is particular to a command, and [`document`] fills in the shared wording
//! wherever an argument has none. `--help`, the manual pages and the completion scripts are
//! all made from the documented tree.

use clap::{Arg, Command};

/// The shared help of an argument by its id, or `None` for one that must document itself.
fn shared(id: &str) -> Option<&'static str> {
    Some(match id {
        "machine" => "The `.kin` model file (a `machine`, optionally followed by a `params` block)",
        "file" => "The `.kin` model file to check",
        "color" => {
            "Colour in diagnostics on standard error: `auto` (only on a terminal, and not when \
             the environment variable NO_COLOR is set and not empty), `always` or `never`"
        }
        "engine" => {
            "What evaluates the model: `jit` (native code, the default) or `interp` (the interpreter, \
             the reference; slower)"
        }
        "format" => {
            "`human` (default) or `json`: one JSON document on standard output (spec/json.md), \
             and on a failure a JSON error document there too"
        }
        "seed" => "Seed of the random draws (the same seed gives the same result)",
        "params" => {
            "Parameter values: a `params { … }` file or a FIT.json written by `kin fit -o` (the \
             machine's own `params` block otherwise); a fit of another revision is refused"
        }
        "components" => {
            "Which error components a point file holds: `position` (ex ey ez) or `pose` (also \
             erx ery erz)"
        }
        "solver" => {
            "How the least-squares problem is solved: `qr` (default; column-pivoted QR, the rank \
             from its diagonal) or `svd` (singular values; the rank from them)"
        }
        "points" => "A point file of measured poses to correct (spec/data.md)",
        _ => return None,
    })
}

/// The placeholder `--help` shows for a file option's value, by the option's id, where the
/// definition names none (clap would print the id in capitals: `--fit <FIT>`).
fn value_name(id: &str) -> Option<&'static str> {
    Some(match id {
        "output" => "OUT",
        "params" => "FILE",
        "candidates" | "validate" | "evaluate" => "FILE",
        "fit" => "FIT.json",
        "diagnose" => "DIAGNOSE.json",
        "model" => "MODEL.kin",
        "dir" => "DIR",
        "axis" => "AXIS",
        "component" => "COMPONENT",
        _ => return None,
    })
}

/// `cmd` and its subcommands with the shared help filled in where an argument has none, and
/// file options given a placeholder that says what they take.
pub fn document(cmd: Command) -> Command {
    cmd.mut_args(|mut arg: Arg| {
        let id = arg.get_id().as_str().to_string();
        // The derive names a value after its field (`FIT`) unless told otherwise.
        let derived = arg
            .get_value_names()
            .is_none_or(|names| names.len() == 1 && names[0].as_str() == id.to_uppercase());
        if derived && !arg.is_positional() {
            if let Some(name) = value_name(&id) {
                arg = arg.value_name(name);
            }
        }
        if arg.get_help().is_some() {
            return arg;
        }
        match shared(&id) {
            Some(text) => arg.help(text),
            None => arg,
        }
    })
    .mut_subcommands(document)
}
