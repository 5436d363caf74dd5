"""Solvers for the MPC's NLP: real-time iteration (RTI), converged SQP, and IPOPT.

* ``rti`` -- one Gauss-Newton SQP step per frame (``sqpmethod`` with
  ``max_iter=1``, QP solver ``qrqp``, Hessian ``J_R^T J_R`` via ``hess_lag``),
  warm-started from the shifted previous solution. Its first frame, and any
  frame after a failure, is solved to convergence by IPOPT so the iteration
  starts near the solution manifold (from a cold start RTI can diverge).
* ``sqp`` -- the same Gauss-Newton SQP iterated to convergence.
* ``ipopt`` -- interior point, primal-dual warm start.

Every solve returns a :class:`SolveResult` with status, iterations and wall
time; failures are values, never exceptions. The exception is Ctrl-C, which
CasADi would turn into a failure status: every call runs in
:func:`capsule_mpc.interrupt.solver_call`, so inside
:func:`capsule_mpc.interrupt.interruptible` (every ``capsule-mpc`` command) it
ends in ``KeyboardInterrupt`` when the solve returns.
"""

from __future__ import annotations

import hashlib
import os
import subprocess
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np

from ..interrupt import raise_if_interrupted, run_interruptibly, solver_call
from .problem import OCP

__all__ = ["QP_SOLVERS", "MPCSolver", "SolveResult", "compiled_sqp"]

#: SQP statuses that mean "a usable step was taken" (RTI stops after one iteration by design).
_SQP_OK = {"Solve_Succeeded", "Maximum_Iterations_Exceeded"}
#: Largest constraint violation (scaled NLP units: mm, cm/s, 0.1 N) an SQP step may leave.
#: One Gauss-Newton step across the smoothed friction's sign change (the capsule starting or
#: stopping) routinely leaves a few units, which the next frames absorb; tens of units mean the
#: linearisation broke down, and the step is rejected (measured on the pipe at 5-45 mm/s).
MAX_STEP_VIOLATION = 20.0
#: IPOPT statuses that give a usable (if not fully converged) point.
_IPOPT_OK = {"Solve_Succeeded", "Solved_To_Acceptable_Level", "Maximum_Iterations_Exceeded"}


@dataclass(frozen=True)
class SolveResult:
    """The outcome of one solve.

    Attributes
    ----------
    success : bool
        Whether ``w`` is a usable, finite solution.
    status : str
        The solver's return status.
    iterations : int
        Iterations taken.
    solve_ms : float
        Wall time of the solve, including the Python call, ms.
    solver : str
        Which solver produced it ('rti', 'sqp' or 'ipopt').
    w, lam_x, lam_g : numpy.ndarray
        Primal solution and multipliers (for the next warm start).
    """

    success: bool
    status: str
    iterations: int
    solve_ms: float
    solver: str
    w: np.ndarray
    lam_x: np.ndarray
    lam_g: np.ndarray


#: QP solvers the SQP schemes can use, with their options. qrqp (active set) is CasADi's own;
#: piqp (interior point) keeps the worst case tight: measured at N = 20 compiled, both give a
#: 1.4 ms median, but qrqp's p99 is ~25 ms (active-set changes at the start of motion and at
#: corners) against ~3 ms for piqp.
QP_SOLVERS: dict[str, dict] = {
    "piqp": {"error_on_fail": False, "piqp": {"verbose": False}},
    "qrqp": {"print_iter": False, "print_header": False, "error_on_fail": False, "max_iter": 50},
}


def _sqp_options(ocp: OCP, max_iter: int, expand: bool, qpsol: str = "piqp") -> dict:
    if qpsol not in QP_SOLVERS:
        raise ValueError(f"mpc.qp_solver: must be one of {sorted(QP_SOLVERS)}, got {qpsol!r}")
    return {
        "qpsol": qpsol,
        "hess_lag": ocp.hess_lag,
        "max_iter": max_iter,
        "max_iter_ls": 0,  # RTI takes the full Gauss-Newton step
        "expand": expand,
        "print_header": False,
        "print_iteration": False,
        "print_time": False,
        "print_status": False,
        "error_on_fail": False,
        "qpsol_options": QP_SOLVERS[qpsol],
    }


def _ipopt_options(ocp: OCP, max_iter: int, expand: bool) -> dict:
    # IPOPT takes the Gauss-Newton Hessian too (upper triangle): measured 20-106 ms per
    # recovery solve at N = 20 against 87-364 ms with its limited-memory approximation.
    w, p = ocp.nlp["x"], ocp.nlp["p"]
    lam_f, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", ocp.nlp["g"].shape[0])
    hess = ca.triu(ocp.hess_lag(w, p, lam_f, lam_g))
    hess_lag = ca.Function("nlp_hess_l", [w, p, lam_f, lam_g], [hess], ["x", "p", "lam_f", "lam_g"],
                           ["triu_hess_gamma_x_x"])  # fmt: skip
    return {
        "expand": expand,
        "print_time": False,
        "error_on_fail": False,
        "hess_lag": hess_lag,
        "ipopt": {
            "print_level": 0,
            "sb": "yes",
            "max_iter": max_iter,
            "tol": 1e-6,
            "acceptable_tol": 1e-4,
        },
    }


def _ipopt_warm_options(ocp: OCP, max_iter: int, expand: bool) -> dict:
    opts = _ipopt_options(ocp, max_iter, expand)
    opts["ipopt"] |= {
        "warm_start_init_point": "yes",
        "warm_start_bound_push": 1e-6,
        "warm_start_mult_bound_push": 1e-6,
        "mu_init": 1e-4,
    }
    return opts


#: Optimisation level for compiled NLP functions: -O1 compiles ~3x faster than -O2 for these
#: large generated files and runs about as fast (measured on the N = 20 problem).
_CFLAGS = ["-O1", "-shared", "-fPIC"]


def compiled_sqp(
    ocp: OCP, name: str, max_iter: int, cache_dir: Path, qpsol: str = "piqp"
) -> tuple[ca.Function, bool]:
    """An ``sqpmethod`` solver whose NLP functions are C code compiled once and cached on disk.

    The shared library is keyed by a hash of the expanded NLP (so any change of model,
    weights or horizon compiles anew) and written atomically. Returns the solver and
    whether it was loaded from the cache.
    """
    nlp_fn = ca.Function("nlp", [ocp.nlp["x"], ocp.nlp["p"]], [ocp.nlp["f"], ocp.nlp["g"]],
                         ["x", "p"], ["f", "g"]).expand()  # fmt: skip
    blob = nlp_fn.serialize() + ocp.hess_lag.expand().serialize() + ca.CasadiMeta.version() + name
    key = hashlib.sha256(blob.encode()).hexdigest()[:16]
    lib = cache_dir / f"mpc_{name}_{key}.so"
    cached = lib.exists()
    if not cached:
        cache_dir.mkdir(parents=True, exist_ok=True)
        solver = run_interruptibly(ca.nlpsol, name, "sqpmethod", ocp.nlp, _sqp_options(ocp, max_iter, True))
        with tempfile.TemporaryDirectory(dir=cache_dir) as tmp:
            gen = ca.CodeGenerator(f"{name}.c")
            for dep in solver.get_function():
                gen.add(solver.get_function(dep))
            gen.add(nlp_fn)
            run_interruptibly(gen.generate, tmp + os.sep)
            out = Path(tmp) / lib.name
            subprocess.run(["gcc", *_CFLAGS, str(Path(tmp) / f"{name}.c"), "-o", str(out)], check=True)
            out.replace(lib)
    opts = _sqp_options(ocp, max_iter, False, qpsol)
    opts["hess_lag"] = ca.external("nlp_hess_l", str(lib))
    return ca.nlpsol(name, "sqpmethod", str(lib), opts), cached


def _nlpsol(name: str, plugin: str, nlp: dict, make_opts) -> ca.Function:
    """Build with SX expansion when the model allows it (faster), else as MX.

    The build runs through :func:`~capsule_mpc.interrupt.run_interruptibly`: seconds of C++
    that would otherwise hold Ctrl-C.
    """
    try:
        return run_interruptibly(ca.nlpsol, name, plugin, nlp, make_opts(True))
    except RuntimeError:  # e.g. a B-spline lookup cannot be expanded to SX
        raise_if_interrupted()
        return run_interruptibly(ca.nlpsol, name, plugin, nlp, make_opts(False))


class MPCSolver:
    """Builds the solvers once; ``solve`` is called every frame.

    Parameters
    ----------
    ocp : OCP
        The problem.
    scheme : {'rti', 'sqp', 'ipopt'}
        The per-frame scheme.
    max_sqp_iter, max_ipopt_iter : int
        Iteration caps.
    qpsol : {'piqp', 'qrqp'}
        QP solver of the SQP schemes (see :data:`QP_SOLVERS`).
    compile_dir : Path, optional
        Compile the SQP's NLP functions to C and cache them here (None: run them in
        CasADi's virtual machine; about 0.6 ms slower per frame at N = 20).
    """

    def __init__(
        self,
        ocp: OCP,
        scheme: str,
        max_sqp_iter: int = 30,
        max_ipopt_iter: int = 200,
        compile_dir: Path | None = None,
        qpsol: str = "piqp",
    ) -> None:
        self.ocp = ocp
        self.scheme = scheme
        self.loaded_from_cache = False
        t0 = time.perf_counter()
        self._ipopt = _nlpsol("mpc_ipopt", "ipopt", ocp.nlp, lambda e: _ipopt_options(ocp, max_ipopt_iter, e))
        self._ipopt_warm = _nlpsol(
            "mpc_ipopt_warm", "ipopt", ocp.nlp, lambda e: _ipopt_warm_options(ocp, max_ipopt_iter, e)
        )
        # Constant bounds converted once (converting NumPy arguments costs ~0.1 ms per call).
        self._bounds = {
            "lbx": ca.DM(ocp.lbw), "ubx": ca.DM(ocp.ubw), "lbg": ca.DM(ocp.lbg), "ubg": ca.DM(ocp.ubg)
        }  # fmt: skip
        self._n_eq = int(np.count_nonzero(ocp.lbg == ocp.ubg))
        self._sqp: ca.Function | None = None
        if scheme in ("rti", "sqp"):
            iters = 1 if scheme == "rti" else max_sqp_iter
            if compile_dir is not None:
                self._sqp, self.loaded_from_cache = compiled_sqp(
                    ocp, "mpc_" + scheme, iters, compile_dir, qpsol
                )
            else:
                self._sqp = _nlpsol(
                    "mpc_" + scheme, "sqpmethod", ocp.nlp, lambda e: _sqp_options(ocp, iters, e, qpsol)
                )
        elif scheme != "ipopt":
            raise ValueError(f"mpc.scheme: must be 'rti', 'sqp' or 'ipopt', got {scheme!r}")
        self.build_s = time.perf_counter() - t0

    def _call(self, fn: ca.Function, kind: str, p: np.ndarray, w0: np.ndarray, lam_x0, lam_g0) -> SolveResult:
        ocp = self.ocp
        args = {"x0": w0, "p": p, **self._bounds}
        if lam_x0 is not None and lam_g0 is not None:
            args |= {"lam_x0": lam_x0, "lam_g0": lam_g0}
        t0 = time.perf_counter()
        try:
            with solver_call():  # Ctrl-C: KeyboardInterrupt after the call, never a failed solve
                sol = fn(**args)
                stats = fn.stats()
        except RuntimeError as exc:  # a solver plugin that raises despite error_on_fail=False
            raise_if_interrupted()
            ms = 1e3 * (time.perf_counter() - t0)
            nan = np.full(ocp.n_w, np.nan)
            return SolveResult(
                False, f"exception: {exc}", 0, ms, kind, nan, nan, np.full(len(ocp.lbg), np.nan)
            )
        ms = 1e3 * (time.perf_counter() - t0)
        w = np.asarray(sol["x"]).ravel()
        status = str(stats.get("return_status", "unknown"))
        ok_set = _IPOPT_OK if kind.startswith("ipopt") else _SQP_OK
        success = status in ok_set and bool(np.all(np.isfinite(w)))
        if success:
            viol = self._violation(w, np.asarray(sol["g"]).ravel())
            if viol > MAX_STEP_VIOLATION:
                success, status = False, f"infeasible step (violation {viol:.3g})"
        return SolveResult(
            success=success,
            status=status,
            iterations=int(stats.get("iter_count", 0)),
            solve_ms=ms,
            solver=kind,
            w=w,
            lam_x=np.asarray(sol["lam_x"]).ravel(),
            lam_g=np.asarray(sol["lam_g"]).ravel(),
        )

    def _violation(self, w: np.ndarray, g: np.ndarray) -> float:
        """Largest bound or constraint violation of ``w`` given ``g(w)`` (scaled NLP units)."""
        ocp = self.ocp
        parts = [ocp.lbg - g, g - ocp.ubg, ocp.lbw - w, w - ocp.ubw]
        return float(max(np.max(np.nan_to_num(v, nan=np.inf, neginf=0.0)) for v in parts))

    def solve_converged(self, p: np.ndarray, w0: np.ndarray, lam_x0=None, lam_g0=None) -> SolveResult:
        """A converged IPOPT solve (cold, or primal-dual warm when multipliers are given)."""
        if lam_x0 is None:
            return self._call(self._ipopt, "ipopt", p, w0, None, None)
        return self._call(self._ipopt_warm, "ipopt_warm", p, w0, lam_x0, lam_g0)

    def solve(self, p: np.ndarray, w0: np.ndarray, lam_x0=None, lam_g0=None) -> SolveResult:
        """One frame's solve with the configured scheme, warm-started at ``w0``."""
        if self._sqp is None:
            return self.solve_converged(p, w0, lam_x0, lam_g0)
        return self._call(self._sqp, self.scheme, p, w0, lam_x0, lam_g0)
