"""Type stubs of the native module `kin._kin` (re-exported by `kin`)."""

from typing import Any, Dict, List, Optional, Sequence, Tuple

import numpy as np
import numpy.typing as npt

F64 = npt.NDArray[np.float64]
# What array arguments accept: anything numpy converts to float64 (lists, integers, float32,
# Fortran-ordered or strided arrays); a C-contiguous float64 array is read in place.
ArrayIn = npt.ArrayLike

__version__: str

class KinError(Exception):
    message: str
    code: Optional[str]
    path: Optional[str]
    line: Optional[int]
    column: Optional[int]
    row: Optional[int]

class CompileError(KinError):
    diagnostics: List[Dict[str, Any]]

class DataError(KinError):
    problems: List[str]

class EvalError(KinError): ...
class FitError(KinError): ...

class Model:
    """A compiled `.kin` model with bound values; immutable; SI units."""

    @staticmethod
    def compile(source: str, params: Optional[str] = None) -> Model: ...
    @staticmethod
    def from_file(path: str, params: Optional[str] = None) -> Model: ...
    @staticmethod
    def from_json(text: str) -> Model: ...
    @staticmethod
    def load(path: str) -> Model: ...
    def with_params(self, params: str) -> Model: ...
    def with_beta(self, beta: ArrayIn) -> Model: ...
    @property
    def name(self) -> str: ...
    @property
    def axes(self) -> List[str]: ...
    @property
    def inputs(self) -> List[str]: ...
    @property
    def tools(self) -> List[str]: ...
    @property
    def coefficients(self) -> List[str]: ...
    @property
    def beta(self) -> F64: ...
    @property
    def source(self) -> str: ...
    @property
    def warnings(self) -> List[str]: ...
    def eval(
        self,
        states: ArrayIn,
        *,
        inputs: Optional[ArrayIn] = None,
        time: Optional[ArrayIn] = None,
        dirs: Optional[ArrayIn] = None,
        tool: int = 0,
        out: Optional[F64] = None,
    ) -> F64: ...
    def eval_jacobian(
        self,
        states: ArrayIn,
        *,
        inputs: Optional[ArrayIn] = None,
        time: Optional[ArrayIn] = None,
        dirs: Optional[ArrayIn] = None,
        tool: int = 0,
        observe: str = "pose",
        out: Optional[F64] = None,
        jac_out: Optional[F64] = None,
    ) -> Tuple[F64, F64]: ...
    def joint_jacobian(self, states: ArrayIn, *, tool: int = 0, out: Optional[F64] = None) -> F64: ...
    def compensate(
        self,
        states: ArrayIn,
        *,
        inputs: Optional[ArrayIn] = None,
        time: Optional[ArrayIn] = None,
        tool: int = 0,
        position_only: bool = False,
        axes: Optional[Sequence[str]] = None,
        out: Optional[F64] = None,
    ) -> F64: ...
    def to_json(self) -> str: ...
    def save(self, path: str) -> None: ...

class StreamingFit:
    """Least squares of β on batches of rows, reduced to a triangle that merges (TSQR)."""

    def __init__(
        self,
        model: Model,
        observe: Optional[Sequence[str]] = None,
        weights: Optional[Sequence[float]] = None,
        block: int = 4096,
    ) -> None: ...
    def add_batch(
        self,
        states: ArrayIn,
        observations: ArrayIn,
        *,
        inputs: Optional[ArrayIn] = None,
        time: Optional[ArrayIn] = None,
        dirs: Optional[ArrayIn] = None,
        tool: int = 0,
    ) -> None: ...
    @property
    def rows(self) -> int: ...
    def r_factor(self) -> F64: ...
    def merge(self, other: StreamingFit) -> None: ...
    def solve(self, tolerance: float = 1e-10) -> Dict[str, Any]: ...

def fit_json(
    model: Model, data: List[str], *, noise: Optional[float] = None, noise_tilt: Optional[float] = None
) -> Tuple[str, str]: ...
def diagnose_json(
    model: Model,
    data: List[str],
    *,
    alpha: float = 0.01,
    noise: Optional[float] = None,
    noise_tilt: Optional[float] = None,
) -> Tuple[str, str, str]: ...
def check_measurements(model: Model, path: str, poses: bool) -> int: ...
def write_measurements_text(
    model: Model, path: str, text: str, *, poses: bool = False, inputs: Sequence[str] = ...
) -> None: ...
def write_files(files: Sequence[Tuple[str, bytes]], inputs: Sequence[str] = ...) -> None: ...
def simulate(
    model: Model,
    path: str,
    n: int,
    *,
    noise: float = 0.0,
    noise_tilt: float = 0.0,
    seed: int = 0,
    observe: Optional[Sequence[str]] = None,
) -> None: ...
def _rust_eval_seconds(model: Model, states: ArrayIn, repeats: int) -> float: ...
