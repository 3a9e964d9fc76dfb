"""kin for Python: compile `.kin` models of multi-axis machines and their geometric errors,
evaluate them on numpy arrays, fit, diagnose and compensate.

>>> import numpy as np, kin
>>> model = kin.Model.compile('''machine slide {
...     task position
...     axis X prismatic along x range 0 mm .. 500 mm
...     tool chain { X moving tool t at (0, 0, -100) mm }
...     errors { X.tx = spline(X, knots 2)  X.ry = const }
... }
... params { X.tx = [2, -1, 0.5, 0.2] um  X.ry[0] = 3 urad }''')
>>> err = model.eval(np.array([[0.25]]))     # (N, 6): ex ey ez erx ery erz, SI
>>> err.shape
(1, 6)

Everything is SI (metres, radians, seconds, kelvin). Evaluation releases the GIL and writes
into `out=` arrays when given. Errors are `KinError` subclasses with the diagnostic's `code`,
`message`, `line` and `column` (`CompileError`), or the file's `path`, `line` and `column`
(`DataError`). See spec/python.md.
"""

from __future__ import annotations

import io
import json
import os
from dataclasses import dataclass, field
from typing import Any, Dict, List, Optional, Sequence, Union

from ._kin import (  # noqa: F401  (re-exported)
    CompileError,
    DataError,
    EvalError,
    FitError,
    KinError,
    Model,
    StreamingFit,
)
from . import _kin

__version__: str = _kin.__version__

__all__ = [
    "Model",
    "StreamingFit",
    "KinError",
    "CompileError",
    "DataError",
    "EvalError",
    "FitError",
    "Coefficient",
    "FitResult",
    "Finding",
    "Diagnosis",
    "fit",
    "diagnose",
    "simulate",
    "read_measurements",
    "write_measurements",
]

PathLike = Union[str, "os.PathLike[str]"]


def _model(model: Union[Model, PathLike]) -> Model:
    return model if isinstance(model, Model) else Model.from_file(os.fspath(model))


def _paths(data: Union[PathLike, Sequence[PathLike]]) -> List[str]:
    if isinstance(data, (str, os.PathLike)):
        return [os.fspath(data)]
    return [os.fspath(p) for p in data]


@dataclass(frozen=True)
class Coefficient:
    """One fitted coefficient, in its display unit (`unit`), with its standard error."""

    name: str
    label: str
    value: float
    se: float
    unit: str
    kept: bool = True
    iso: Optional[str] = None


def _html_table(rows: Sequence[Sequence[str]], head: Sequence[str]) -> str:
    import html

    cells = "".join(f"<th>{html.escape(h)}</th>" for h in head)
    body = "".join(
        "<tr>" + "".join(f"<td>{html.escape(str(c))}</td>" for c in r) + "</tr>" for r in rows
    )
    return f"<table><tr>{cells}</tr>{body}</table>"


@dataclass(repr=False)
class FitResult:
    """A fit (FIT.json's document): `sigma` (σ̂, in `error_unit`), `rms`, `rows`, `rank`,
    `coefficients` with names and standard errors, `residuals` as a DataFrame, `params` (the
    FIT.params text), and `document` (the whole FIT.json as a dict)."""

    document: Dict[str, Any]
    params: str
    coefficients: List[Coefficient] = field(default_factory=list)

    @classmethod
    def _from(cls, text: str, params: str) -> "FitResult":
        doc = json.loads(text)
        coefs = [
            Coefficient(
                name=c["name"],
                label=c.get("label", ""),
                value=float("nan") if c.get("value") is None else c["value"],
                se=float("nan") if c.get("se") is None else c["se"],
                unit=c.get("unit", ""),
                kept=c.get("kept", True),
                iso=c.get("iso"),
            )
            for c in doc.get("coefficients", [])
        ]
        return cls(document=doc, params=params, coefficients=coefs)

    @property
    def sigma(self) -> float:
        return self.document["sigma"]

    @property
    def rms(self) -> float:
        return self.document["rms"]

    @property
    def rows(self) -> int:
        return self.document["rows"]

    @property
    def rank(self) -> int:
        return self.document["rank"]

    @property
    def error_unit(self) -> str:
        return self.document["error_unit"]

    @property
    def residuals(self):
        """Every residual (up to 200 000 rows) as a pandas DataFrame: file, line, component,
        observed, residual, studentized, leverage, cook (display units)."""
        import pandas as pd

        cols = ["file", "line", "component", "observed", "residual", "studentized", "leverage", "cook"]
        return pd.DataFrame(self.document.get("residuals", []), columns=cols)

    def coefficient_table(self):
        """The coefficients as a DataFrame indexed by name."""
        import pandas as pd

        return pd.DataFrame([c.__dict__ for c in self.coefficients]).set_index("name")

    def to_json(self) -> str:
        return json.dumps(self.document)

    def __repr__(self) -> str:
        # The whole document is megabytes (every residual): a line that says what it is.
        return (
            f"<kin.FitResult {self.document.get('machine', '?')}: {self.rows} rows, "
            f"{len(self.coefficients)} coefficients (rank {self.rank}), "
            f"σ̂ = {self.sigma:.4g} {self.error_unit}, RMS {self.rms:.4g}>"
        )

    def _repr_html_(self) -> str:
        head = (
            f"<p><b>kin fit</b> of <code>{self.document.get('machine', '?')}</code>: "
            f"{self.rows} rows, rank {self.rank}, σ̂ = {self.sigma:.4g} {self.error_unit}</p>"
        )
        rows = [
            (c.name, c.iso or "", f"{c.value:.4g}", f"{c.se:.2g}", c.unit)
            for c in self.coefficients[:50]
        ]
        more = (
            f"<p>… and {len(self.coefficients) - 50} more (coefficient_table())</p>"
            if len(self.coefficients) > 50
            else ""
        )
        return head + _html_table(rows, ["coefficient", "ISO", "value", "se", "unit"]) + more

    def write(self, path: PathLike, inputs: Sequence[PathLike] = ()) -> None:
        """Writes FIT.json at `path` and FIT.params beside it, atomically and as one set (as
        `kin fit -o`); refuses a `path` that names one of `inputs`."""
        path = os.fspath(path)
        params = os.path.splitext(path)[0] + ".params"
        _kin.write_files(
            [(path, self.to_json().encode()), (params, self.params.encode())],
            [os.fspath(p) for p in inputs],
        )


@dataclass(frozen=True)
class Finding:
    """A tested candidate effect: `line` is the exact `.kin` line to add in `errors { … }`,
    `explanation` what it means physically, `significant` after Holm–Bonferroni correction."""

    line: str
    target: str
    explanation: str
    family: str
    significant: bool
    p: float
    p_adjusted: float
    explained: float
    rms_after: float
    bic: float
    alternatives: List[str]


@dataclass(repr=False)
class Diagnosis:
    """`kin diagnose`'s result: the fit it started from, `findings` ranked (lower ΔBIC first),
    `sigma` and `rms` of the fit, and `document` (DIAGNOSE.json as a dict)."""

    fit: FitResult
    document: Dict[str, Any]
    findings: List[Finding]

    @property
    def sigma(self) -> float:
        return self.document["sigma"]

    @property
    def rms(self) -> float:
        return self.document["rms"]

    @property
    def top(self) -> Optional[Finding]:
        """The first significant finding, if any."""
        return next((f for f in self.findings if f.significant), None)

    def __repr__(self) -> str:
        significant = sum(1 for f in self.findings if f.significant)
        top = self.top
        return (
            f"<kin.Diagnosis {self.document.get('machine', '?')}: {significant} of "
            f"{len(self.findings)} candidates significant"
            + (f"; first: {top.line}" if top is not None else "")
            + ">"
        )

    def _repr_html_(self) -> str:
        rows = [
            (f.line, f.family, f"{100 * f.explained:.1f} %", f"{f.p_adjusted:.2g}", f.explanation)
            for f in self.findings
            if f.significant
        ][:20]
        head = f"<p><b>kin diagnose</b>: {len(rows)} significant candidate(s)</p>"
        return head + _html_table(rows, ["line", "family", "explains", "adjusted p", "meaning"])

    def write(self, path: PathLike, inputs: Sequence[PathLike] = ()) -> None:
        """Writes DIAGNOSE.json at `path` atomically."""
        _kin.write_files(
            [(os.fspath(path), json.dumps(self.document).encode())],
            [os.fspath(p) for p in inputs],
        )


def fit(
    model: Union[Model, PathLike],
    data: Union[PathLike, Sequence[PathLike]],
    *,
    noise: Optional[float] = None,
    noise_tilt: Optional[float] = None,
) -> FitResult:
    """Fits `model` (a Model or a .kin path) to measurement files, as `kin fit` does; `noise`
    (m) and `noise_tilt` (rad) weight rows by the instrument's stated noise."""
    text, params = _kin.fit_json(_model(model), _paths(data), noise=noise, noise_tilt=noise_tilt)
    return FitResult._from(text, params)


def diagnose(
    model: Union[Model, PathLike],
    data: Union[PathLike, Sequence[PathLike]],
    *,
    alpha: float = 0.01,
    noise: Optional[float] = None,
    noise_tilt: Optional[float] = None,
) -> Diagnosis:
    """Fits and diagnoses as `kin diagnose` does: where the model fails and which candidate
    lines would explain it."""
    fit_text, params, diag_text = _kin.diagnose_json(
        _model(model), _paths(data), alpha=alpha, noise=noise, noise_tilt=noise_tilt
    )
    doc = json.loads(diag_text)
    findings = []
    for f in doc.get("findings", []):
        c = f["candidate"]
        findings.append(
            Finding(
                line=c["text"],
                target=c["target"],
                explanation=c["explanation"],
                family=str(c["family"]),
                significant=f["significant"],
                p=f["p"],
                p_adjusted=f["p_adjusted"],
                explained=f["explained"],
                rms_after=f["rms_after"],
                bic=f.get("bic", float("nan")),
                alternatives=[a["text"] for a in f.get("alternatives", [])],
            )
        )
    return Diagnosis(fit=FitResult._from(fit_text, params), document=doc, findings=findings)


def simulate(
    model: Union[Model, PathLike],
    path: PathLike,
    n: int,
    *,
    noise: float = 0.0,
    noise_tilt: float = 0.0,
    seed: int = 0,
    observe: Optional[Sequence[str]] = None,
) -> None:
    """Writes a measurement file of `n` states sampled in the model's ranges, with the model's
    bound β applied by the exact transforms and Gaussian noise (as `kin simulate --sample`)."""
    _kin.simulate(
        _model(model), os.fspath(path), n, noise=noise, noise_tilt=noise_tilt, seed=seed,
        observe=list(observe) if observe is not None else None,
    )


def _rows_text(path: str) -> str:
    """The file without its comment lines (a line whose first non-blank character is `#`) and
    without a byte order mark, as spec/data.md defines them; blank lines pandas skips itself."""
    with open(path, encoding="utf-8-sig", newline="") as f:
        return "".join(line for line in f if not line.lstrip().startswith("#"))


def _delimiter(text: str) -> str:
    """The separator kin detects from the header (spec/data.md): of `,`, `;` and tab, the one
    the header line holds most often outside quotes; a comma when it holds none."""
    header = next((l for l in text.splitlines() if l.strip()), "")
    counts = {",": 0, ";": 0, "\t": 0}
    quoted = False
    for ch in header:
        if ch == '"':
            quoted = not quoted
        elif not quoted and ch in counts:
            counts[ch] += 1
    best = max(counts, key=lambda d: counts[d])
    return best if counts[best] > 0 else ","


def read_measurements(model: Union[Model, PathLike], path: PathLike, *, poses: bool = False):
    """A measurement file as a pandas DataFrame, columns named as in the file's header
    (`X[mm]`, `ex[um]` …). The file is first read by kin's own reader against `model`, so a
    wrong file raises DataError with its line and column instead of giving a wrong frame."""
    import pandas as pd

    path = os.fspath(path)
    _kin.check_measurements(_model(model), path, poses)
    text = _rows_text(path)
    sep = _delimiter(text)
    return pd.read_csv(
        io.StringIO(text),
        sep=sep,
        decimal="," if sep != "," else ".",
        skipinitialspace=True,
        skip_blank_lines=True,
        dtype={"tool": str, "artifact": str},
    )


def write_measurements(
    df,
    model: Union[Model, PathLike],
    path: PathLike,
    *,
    comments: Sequence[str] = (),
    poses: bool = False,
    inputs: Sequence[PathLike] = (),
) -> None:
    """Writes a DataFrame (columns named as a measurement file's header: `X[mm]`, `dir_X`,
    `ex[um]` …) as a measurement file, atomically. The text is read back by kin's reader
    against `model` first: nothing is written when it would not read (DataError)."""
    buf = io.StringIO()
    for c in comments:
        buf.write(f"# {c}\n")
    # repr-exact floats: what is read back is what was written.
    df.to_csv(buf, index=False, lineterminator="\n", float_format=None)
    _kin.write_measurements_text(
        _model(model), os.fspath(path), buf.getvalue(), poses=poses,
        inputs=[os.fspath(p) for p in inputs],
    )
