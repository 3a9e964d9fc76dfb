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

/// `cmd` and its subcommands with the shared help filled in where an argument has none.
pub fn document(cmd: Command) -> Command {
    cmd.mut_args(|arg: Arg| {
        if arg.get_help().is_some() {
            return arg;
        }
        match shared(arg.get_id().as_str()) {
            Some(text) => arg.help(text),
            None => arg,
        }
    })
    .mut_subcommands(document)
}
