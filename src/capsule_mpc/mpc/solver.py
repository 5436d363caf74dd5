"""Solvers for the MPC's NLP: real-time iteration (RTI) around a structured QP, SQP, and IPOPT.

* ``rti`` -- one Gauss-Newton SQP step per frame, warm-started from the shifted previous
  solution: ONE CasADi Function (:func:`rti_function`) that linearises the stage-wise NLP
  (:mod:`capsule_mpc.mpc.problem`; Hessian ``J_R^T J_R``), solves the QP with the chosen
  ``conic`` plugin (``hpipm`` by default: a Riccati-structured interior point that uses the
  layout) and returns the new iterate and its constraint violation. Called through CasADi's
  buffer interface (:class:`FastCall`: NumPy arrays in and out, no DM conversion), without
  option dicts or ``stats()`` on the frame.
* ``sqp`` -- the same step iterated with a backtracking line search on the l1 merit function
  (:meth:`MPCSolver.sqp`), to convergence (:data:`MAX_SQP_ITER`). The controller also uses a
  few of these iterations to recover a frame whose RTI step failed.
* ``ipopt`` -- interior point, primal-dual warm start; also the converged solve of the first
  frame of the SQP schemes (from a cold start RTI can diverge).

The NLP's derivatives (``mpc_qp_data``) and values (``mpc_merit``) can be compiled to C once and
cached on disk (``compile_dir``; a library is checked against its checksum before it is loaded,
see :mod:`capsule_mpc.cache`). Every solve returns a :class:`SolveResult` with status,
iterations and wall time; failures are values, never exceptions. The exception is Ctrl-C, which
CasADi would turn into a failure status: every call runs in
:func:`capsule_mpc.interrupt.solver_call`, so inside :func:`capsule_mpc.interrupt.interruptible`
(every ``capsule-mpc`` command) it ends in ``KeyboardInterrupt`` when the solve returns.
"""

from __future__ import annotations

import hashlib
import inspect
import os
import signal
import subprocess
import time
from dataclasses import dataclass
from pathlib import Path

import casadi as ca
import numpy as np

from ..cache import load_or_build, usable_folder
from ..interrupt import raise_if_interrupted, run_interruptibly, solver_call
from .problem import N_REF, N_STATE, OCP, STATE_SCALE, U_SCALE, X_SCALE

__all__ = [
    "HPIPM_OPTIONS",
    "MAX_IPOPT_ITER",
    "MAX_SQP_ITER",
    "MAX_STEP_VIOLATION",
    "QP_SOLVERS",
    "FastCall",
    "MPCSolver",
    "SolveResult",
    "compiled_nlp_functions",
    "l1_merit_function",
    "nlp_cache_key",
    "nlp_functions",
    "qp_function",
    "qp_options",
    "rti_function",
]

#: Largest constraint violation (scaled NLP units: mm, cm/s, 0.1 N) an SQP step may leave.
#: One Gauss-Newton step across the smoothed friction's sign change (the capsule starting or
#: stopping) routinely leaves a few units, which the next frames absorb; tens of units mean the
#: linearisation broke down, and the step is rejected (measured on the pipe at 5-45 mm/s).
MAX_STEP_VIOLATION = 20.0
#: Iteration cap of the sqp scheme's solve to convergence (a frame's recovery has its own, far
#: smaller, ``mpc.recovery_sqp_iter``): SQP with a line search converges in a handful of
#: iterations from a warm start; the cap only bounds a pathological solve.
MAX_SQP_ITER = 30
#: Iteration cap of IPOPT's solves (the first frame's cold solve, the ipopt scheme): IPOPT's own
#: cap is 3000; a cold start of this problem converges in tens of iterations.
MAX_IPOPT_ITER = 200
#: IPOPT statuses that give a usable (if not fully converged) point.
_IPOPT_OK = {"Solve_Succeeded", "Solved_To_Acceptable_Level", "Maximum_Iterations_Exceeded"}
#: QP solvers the SQP schemes can use on the stage-wise layout.
QP_SOLVERS = ("hpipm", "piqp")
#: HPIPM settings: 'speed' mode with residual tolerances in the QP's scaled units and a cap of 10
#: interior-point iterations (against piqp solved to 1e-10 the first command stays within a fraction
#: of a mm/s; 'speed_abs' is far off, 'balance' slower), and an initial barrier parameter ``mu0`` of
#: 3 instead of the mode's 10, as the QP is scaled to unit order: fewer iterations per QP and fewer
#: QPs left at the cap on recorded closed-loop QPs (``benchmarks/hpipm_mu0.py``; docs/results.md,
#: "HPIPM's initial barrier parameter").
HPIPM_OPTIONS = {
    "mode": "speed",
    "mu0": 3.0,
    "res_g_max": 1e-4,
    "res_b_max": 1e-6,
    "res_d_max": 1e-6,
    "res_m_max": 1e-6,
    "iter_max": 10,
}
#: Line search of the SQP: Armijo constant, step-length factor and the most trial steps.
_ARMIJO, _BACKTRACK, _MAX_LINE_SEARCH = 1e-4, 0.5, 6
#: SQP convergence: largest step (scaled units: um, 0.1 mm/s) and constraint violation.
_SQP_STEP_TOL, _SQP_VIOLATION_TOL = 1e-3, 1e-4
#: Margin of the l1 penalty weight over the largest QP multiplier (exact-penalty condition).
_PENALTY_MARGIN = 1.1


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
    w : numpy.ndarray
        Primal solution (scaled, stage-wise).
    lam_x, lam_g : numpy.ndarray
        Multipliers (IPOPT's, for its next warm start; empty for the SQP schemes).
    violation : float
        Largest constraint violation of ``w`` (scaled units; NaN if not evaluated).
    """

    success: bool
    status: str
    iterations: int
    solve_ms: float
    solver: str
    w: np.ndarray
    lam_x: np.ndarray
    lam_g: np.ndarray
    violation: float = float("nan")


#: Multipliers of a solve that has none to hand on.
_NO_MULTIPLIERS = np.empty(0)


def qp_options(qpsol: str, ocp: OCP) -> dict:
    """``conic`` options of QP solver ``qpsol`` on ``ocp``'s layout (``error_on_fail`` off:
    a failed QP shows as a bad step, which the caller checks)."""
    if qpsol == "hpipm":
        return {**ocp.structure, "error_on_fail": False, "hpipm": dict(HPIPM_OPTIONS)}
    if qpsol == "piqp":
        return {"error_on_fail": False, "piqp": {"verbose": False}}
    raise ValueError(f"mpc.qp_solver: must be one of {list(QP_SOLVERS)}, got {qpsol!r}")


def nlp_functions(ocp: OCP, expand: bool = True) -> tuple[ca.Function, ca.Function]:
    """The NLP's derivative and value functions, ``(mpc_qp_data, mpc_merit)``.

    ``mpc_qp_data(w, p) -> (H, grad, g, Jg)``: the Gauss-Newton Hessian ``J_R^T J_R`` (block
    diagonal by stage), the objective's gradient, the constraints and their Jacobian.
    ``mpc_merit(w, p) -> (f, g)``: objective and constraints. With ``expand`` both are SX
    (faster; a B-spline force lookup cannot be expanded, then pass False).
    """
    w, p = ocp.nlp["x"], ocp.nlp["p"]
    r = ocp.residual(w, p)
    jac = ca.jacobian(r, w)
    g = ocp.nlp["g"]
    grad = ca.mtimes(jac.T, r) + ca.DM(ocp.slack_gradient)
    qp_data = ca.Function(
        "mpc_qp_data",
        [w, p],
        [ca.mtimes(jac.T, jac), grad, g, ca.jacobian(g, w)],
        ["w", "p"],
        ["H", "grad", "g", "Jg"],
    )
    merit = ca.Function("mpc_merit", [w, p], [ocp.nlp["f"], g], ["w", "p"], ["f", "g"])
    if expand:
        return qp_data.expand(), merit.expand()
    return qp_data, merit


def _linearisation_point(ocp: OCP, w: ca.MX, p: ca.MX) -> tuple[ca.MX, ca.MX, ca.MX]:
    """``w`` with stage 0 set from the parameters, and the variable bounds (``x_0`` fixed)."""
    # The model's state, then the command and its slope: p = (x0, ref, u_prev, slope_prev, d, dmu).
    nx, nu = len(X_SCALE), 2 * len(U_SCALE)
    i_u = nx + N_REF * ocp.horizon
    x0 = ca.vertcat(p[0:nx], p[i_u : i_u + nu]) / ca.DM(STATE_SCALE)
    w_lin = ca.vertcat(x0, w[N_STATE:])
    lbw = ca.vertcat(x0, ca.DM(ocp.lbw[N_STATE:]))
    ubw = ca.vertcat(x0, ca.DM(ocp.ubw[N_STATE:]))
    return w_lin, lbw, ubw


def _qp_arguments(ocp: OCP, qp_data: ca.Function, w: ca.MX, p: ca.MX) -> tuple[ca.MX, ca.MX, ca.MX, dict]:
    """The Gauss-Newton QP in the step ``dw`` at ``w`` (stage 0 from ``p``): ``(w_lin, grad, g,
    args)``, ``args`` as ``conic`` takes them (``h, g, a, lba, uba, lbx, ubx``)."""
    w_lin, lbw, ubw = _linearisation_point(ocp, w, p)
    hess, grad, g, jac_g = qp_data(w_lin, p)
    args = {
        "h": hess,
        "g": grad,
        "a": jac_g,
        "lba": ca.DM(ocp.lbg) - g,
        "uba": ca.DM(ocp.ubg) - g,
        "lbx": lbw - w_lin,
        "ubx": ubw - w_lin,
    }
    return w_lin, grad, g, args


def qp_function(ocp: OCP, qp_data: ca.Function) -> ca.Function:
    """``mpc_qp(w, p) -> (h, g, a, lba, uba, lbx, ubx, w_lin)``: the QP an RTI step from ``w``
    solves (in the step ``dw``; ``w_lin``: ``w`` with stage 0 from ``p``), as ``conic`` takes it --
    to solve a recorded frame's QP again with other QP settings."""
    w, p = ca.MX.sym("w", ocp.n_w), ca.MX.sym("p", ocp.n_p)
    w_lin, _grad, _g, args = _qp_arguments(ocp, qp_data, w, p)
    return ca.Function("mpc_qp", [w, p], [*args.values(), w_lin], ["w", "p"], [*args, "w_lin"])


def _qp_step(
    ocp: OCP, qp_data: ca.Function, qpsol: str, w: ca.MX, p: ca.MX, opts: dict | None = None
) -> tuple[ca.MX, ...]:
    """The Gauss-Newton QP at ``w`` (stage 0 from ``p``) solved: ``(w_lin, dw, lam_g, grad, g)``."""
    w_lin, grad, g, args = _qp_arguments(ocp, qp_data, w, p)
    opts = qp_options(qpsol, ocp) if opts is None else opts
    qp = ca.conic("mpc_qp", qpsol, {"h": args["h"].sparsity(), "a": args["a"].sparsity()}, opts)
    sol = qp(**args)
    return w_lin, sol["x"], sol["lam_a"], grad, g


def _violation_expr(ocp: OCP, g: ca.MX) -> ca.MX:
    """Largest violation of ``lbg <= g <= ubg``."""
    return ca.mmax(ca.fmax(ca.DM(ocp.lbg) - g, g - ca.DM(ocp.ubg)))


def _l1_violation_expr(ocp: OCP, g: ca.MX) -> ca.MX:
    """Sum of the violations of ``lbg <= g <= ubg`` (the l1 merit's penalty term)."""
    return ca.sum1(ca.fmax(0, ca.DM(ocp.lbg) - g) + ca.fmax(0, g - ca.DM(ocp.ubg)))


def rti_function(
    ocp: OCP, qp_data: ca.Function, merit: ca.Function, qpsol: str = "hpipm", opts: dict | None = None
) -> ca.Function:
    """The RTI step as one CasADi Function
    ``mpc_rti(w, p) -> (w_next, violation, lam_max, f_lin, l1_lin, slope)``.

    Stage 0 of ``w`` is replaced by the parameters' state and command (``w_lin``), the NLP is
    linearised there (Gauss-Newton Hessian), the QP is solved by ``qpsol`` and the full step
    ``dw`` taken: ``w_next = w_lin + dw``, with ``violation`` its largest constraint violation.
    The other outputs serve the line search of :meth:`MPCSolver.sqp`: the largest QP multiplier,
    the objective and the l1 constraint violation at ``w_lin`` and the objective's slope along
    ``dw``. ``opts`` replaces :func:`qp_options`' options of the QP solver. (The multipliers must
    be used: CasADi 3.8.2's HPIPM interface writes them unconditionally, and crashes when a
    Function leaves that output unallocated.)
    """
    w, p = ca.MX.sym("w", ocp.n_w), ca.MX.sym("p", ocp.n_p)
    w_lin, dw, lam_g, grad, g = _qp_step(ocp, qp_data, qpsol, w, p, opts)
    w_next = w_lin + dw
    f_lin, _g = merit(w_lin, p)
    _f, g_next = merit(w_next, p)
    outputs = [w_next, _violation_expr(ocp, g_next), ca.mmax(ca.fabs(lam_g)), f_lin]
    outputs += [_l1_violation_expr(ocp, g), ca.dot(grad, dw)]
    names = ["w_next", "violation", "lam_max", "f_lin", "l1_lin", "slope"]
    return ca.Function("mpc_rti", [w, p], outputs, ["w", "p"], names)


def l1_merit_function(ocp: OCP, merit: ca.Function) -> ca.Function:
    """``mpc_l1_merit(w, p) -> (f, l1, violation)``: the objective, the sum and the largest of the
    constraint violations."""
    w, p = ca.MX.sym("w", ocp.n_w), ca.MX.sym("p", ocp.n_p)
    f, g = merit(w, p)
    return ca.Function("mpc_l1_merit", [w, p], [f, _l1_violation_expr(ocp, g), _violation_expr(ocp, g)])


class FastCall:
    """A CasADi Function called through its buffer interface: NumPy arrays in and out.

    The arguments and results live in arrays allocated once and bound to the Function's buffer,
    so a call converts nothing (building DMs from NumPy and ``.full()`` back cost ~0.2 ms per RTI
    step at N = 20). Every input and output must be dense. Results are returned as copies.
    """

    def __init__(self, fn: ca.Function) -> None:
        dense = all(fn.sparsity_in(i).is_dense() for i in range(fn.n_in()))
        if not dense or not all(fn.sparsity_out(i).is_dense() for i in range(fn.n_out())):
            raise ValueError(f"FastCall: {fn.name()} has a sparse input or output")
        self.fn = fn
        self._args = [np.zeros(fn.nnz_in(i)) for i in range(fn.n_in())]
        self._res = [np.zeros(fn.nnz_out(i)) for i in range(fn.n_out())]
        self._buffer, self._trigger = fn.buffer()
        # (The size argument of the C++ signature is taken from the memoryview by the binding.)
        for i, arg in enumerate(self._args):
            self._buffer.set_arg(i, memoryview(arg))  # type: ignore[call-arg]
        for i, res in enumerate(self._res):
            self._buffer.set_res(i, memoryview(res))  # type: ignore[call-arg]

    def __call__(self, *args: np.ndarray) -> list[np.ndarray]:
        """``fn(*args)`` as flat arrays."""
        for dest, value in zip(self._args, args, strict=True):
            dest[:] = value
        self._trigger()
        return [res.copy() for res in self._res]


def _ipopt_options(ocp: OCP, max_iter: int, expand: bool, warm: bool) -> dict:
    # IPOPT takes the Gauss-Newton Hessian (upper triangle): measured 20-106 ms per solve at
    # N = 20 against 87-364 ms with its limited-memory approximation.
    w, p = ocp.nlp["x"], ocp.nlp["p"]
    lam_f, lam_g = ca.MX.sym("lam_f"), ca.MX.sym("lam_g", ocp.nlp["g"].shape[0])
    jac = ca.jacobian(ocp.residual(w, p), w)
    hess = lam_f * ca.triu(ca.mtimes(jac.T, jac))
    hess_lag = ca.Function(
        "nlp_hess_l", [w, p, lam_f, lam_g], [hess], ["x", "p", "lam_f", "lam_g"], ["triu_hess_gamma_x_x"]
    )
    ipopt = {"print_level": 0, "sb": "yes", "max_iter": max_iter, "tol": 1e-6, "acceptable_tol": 1e-4}
    if warm:
        ipopt |= {
            "warm_start_init_point": "yes",
            "warm_start_bound_push": 1e-6,
            "warm_start_mult_bound_push": 1e-6,
            "mu_init": 1e-4,
        }
    return {
        "expand": expand,
        "print_time": False,
        "error_on_fail": False,
        "hess_lag": hess_lag,
        "ipopt": ipopt,
    }


#: Optimisation level for compiled NLP functions: -O1 compiles ~3x faster than -O2 for these
#: large generated files and runs about as fast (measured on the N = 20 problem).
_CFLAGS = ["-O1", "-shared", "-fPIC"]


def nlp_cache_key(ocp: OCP) -> str:
    """The key of ``ocp``'s compiled NLP functions on disk.

    A hash of what defines them: the problem (residuals, constraints and objective as one MX
    graph, so any change of model, weights or horizon compiles anew), the code that derives the
    functions from it (:func:`nlp_functions`), the compiler flags and the CasADi version. It takes
    ~10 ms; hashing the expanded functions themselves took ~0.07 s on top of the ~0.05 s of
    building them, both of which a start from the cache now skips.
    """
    w, p = ocp.nlp["x"], ocp.nlp["p"]
    outputs = [ocp.residual(w, p), ocp.nlp["g"], ocp.nlp["f"]]
    definition = ca.Function("mpc_nlp_definition", [w, p], outputs)
    code = inspect.getsource(nlp_functions)
    parts = [definition.serialize(), code, " ".join(_CFLAGS), ca.CasadiMeta.version()]
    return hashlib.sha256("\n".join(parts).encode()).hexdigest()[:16]


def _gcc(source: str, out: Path) -> None:
    """Compile ``source`` (a C file in ``out``'s folder) to the shared library ``out``.

    gcc runs in that folder with relative names (the library does not depend on the folder's
    name), puts its temporary files there, and runs in its own process group: whatever ends the
    call (Ctrl-C included) kills gcc and the compilers it started.

    Raises
    ------
    OSError
        No gcc.
    RuntimeError
        gcc failed (its first error line).
    """
    command = ["gcc", *_CFLAGS, source, "-o", out.name]
    env = {**os.environ, "TMPDIR": str(out.parent)}
    with subprocess.Popen(
        command,
        cwd=out.parent,
        env=env,
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
        encoding="utf-8",
        errors="replace",
        start_new_session=True,
    ) as gcc:
        try:
            _, err = gcc.communicate()
        except BaseException:
            try:
                os.killpg(gcc.pid, signal.SIGKILL)
            except ProcessLookupError:
                pass
            raise
    if gcc.returncode != 0:
        lines = err.strip().splitlines() or ["no message"]
        first_error = next((line for line in lines if "error" in line), lines[-1])
        raise RuntimeError(f"gcc failed (exit {gcc.returncode}): {first_error}")


class _NotExpandable(Exception):
    """The problem cannot be expanded to SX: there is no C code to generate."""


def compiled_nlp_functions(ocp: OCP, cache_dir: Path) -> tuple[ca.Function, ca.Function, bool] | None:
    """``ocp``'s NLP derivative and value functions (:func:`nlp_functions`) as C code compiled once
    and cached on disk.

    The shared library is named by :func:`nlp_cache_key` and stored with its checksum
    (:func:`capsule_mpc.cache.load_or_build`): one that fails the checksum (truncated, modified) is
    never loaded, and one that does not load or was compiled for another problem size is replaced.
    It is generated and compiled in a temporary folder inside ``cache_dir``, removed whatever ends
    the build; an unwritable ``cache_dir`` is replaced by a temporary one, with a warning.

    Returns
    -------
    tuple or None
        The two functions loaded from the library and whether it came from the cache; None when
        the problem cannot be expanded to SX (e.g. a B-spline lookup), so there is nothing to
        compile.

    Raises
    ------
    OSError, RuntimeError
        No C compiler, or compiling failed.
    """
    lib = usable_folder(cache_dir) / f"mpc_nlp_{nlp_cache_key(ocp)}.so"

    def build(out: Path) -> None:
        qp_data, merit, expanded = _expanded_nlp_functions(ocp)
        if not expanded:
            raise _NotExpandable
        gen = ca.CodeGenerator("mpc_nlp.c")
        gen.add(qp_data)
        gen.add(merit)
        run_interruptibly(gen.generate, str(out.parent) + os.sep)
        _gcc("mpc_nlp.c", out)

    def load(path: Path) -> tuple[ca.Function, ca.Function]:
        qp_data, merit = ca.external("mpc_qp_data", str(path)), ca.external("mpc_merit", str(path))
        n_w, n_p = qp_data.size1_in(0), qp_data.size1_in(1)
        if (n_w, n_p) != (ocp.n_w, ocp.n_p):
            raise ValueError(f"compiled for {n_w} variables, {n_p} parameters, not {ocp.n_w}, {ocp.n_p}")
        return qp_data, merit

    try:
        (qp_data, merit), cached = load_or_build(lib, build, load)
    except _NotExpandable:
        return None
    return qp_data, merit, cached


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


def _expanded_nlp_functions(ocp: OCP) -> tuple[ca.Function, ca.Function, bool]:
    try:
        return (*nlp_functions(ocp, expand=True), True)
    except RuntimeError:  # a B-spline lookup cannot be expanded to SX
        raise_if_interrupted()
        return (*nlp_functions(ocp, expand=False), False)


class MPCSolver:
    """Builds the solvers once; ``solve`` is called every frame.

    Parameters
    ----------
    ocp : OCP
        The problem (stage-wise layout).
    scheme : {'rti', 'sqp', 'ipopt'}
        The per-frame scheme.
    compile_dir : Path, optional
        Compile the NLP's derivative and value functions to C and cache them here (None: run
        them in CasADi's virtual machine).
    qpsol : {'hpipm', 'piqp'}
        QP solver of the SQP schemes (see :func:`qp_options`).
    """

    def __init__(
        self,
        ocp: OCP,
        scheme: str,
        compile_dir: Path | None = None,
        qpsol: str = "hpipm",
    ) -> None:
        if scheme not in ("rti", "sqp", "ipopt"):
            raise ValueError(f"mpc.scheme: must be 'rti', 'sqp' or 'ipopt', got {scheme!r}")
        qp_options(qpsol, ocp)  # validates the name
        self.ocp = ocp
        self.scheme = scheme
        self.qpsol = qpsol
        self.loaded_from_cache = False
        self.compiled = False
        t0 = time.perf_counter()
        self._ipopt = _nlpsol(
            "mpc_ipopt", "ipopt", ocp.nlp, lambda e: _ipopt_options(ocp, MAX_IPOPT_ITER, e, False)
        )
        # The primal-dual warm-started IPOPT only where it runs every frame (0.08 s to build).
        self._ipopt_warm: ca.Function | None = None
        if scheme == "ipopt":
            self._ipopt_warm = _nlpsol(
                "mpc_ipopt_warm", "ipopt", ocp.nlp, lambda e: _ipopt_options(ocp, MAX_IPOPT_ITER, e, True)
            )
        # Constant bounds converted once (converting NumPy arguments costs ~0.1 ms per call).
        self._bounds = {"lbg": ca.DM(ocp.lbg), "ubg": ca.DM(ocp.ubg)}
        compiled = None if compile_dir is None else compiled_nlp_functions(ocp, compile_dir)
        if compiled is None:
            qp_data, merit, _expanded = _expanded_nlp_functions(ocp)
        else:
            qp_data, merit, self.loaded_from_cache = compiled
            self.compiled = True
        self._rti = FastCall(rti_function(ocp, qp_data, merit, qpsol))
        self._merit = FastCall(l1_merit_function(ocp, merit))
        #: The last step: its arguments and the RTI function's outputs (a recovery from the same
        #: guess starts with it instead of solving the same QP again).
        self._last_step: tuple[np.ndarray, np.ndarray, list[np.ndarray]] | None = None
        self.build_s = time.perf_counter() - t0

    # ------------------------------------------------------------------ IPOPT
    def _call(
        self, fn: ca.Function, kind: str, p: np.ndarray, w0: np.ndarray, lam_x0, lam_g0, bounds=None
    ) -> SolveResult:
        """One IPOPT call (``bounds``: ``lbx``/``ubx`` for this call, with ``x_0`` fixed)."""
        ocp = self.ocp
        args = {"x0": w0, "p": p, **self._bounds, **(bounds or {})}
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
        success = status in _IPOPT_OK and bool(np.all(np.isfinite(w)))
        viol = float("nan")
        if success:
            g = np.asarray(sol["g"]).ravel()
            viol = float(max(np.max(ocp.lbg - g), np.max(g - ocp.ubg)))
            if viol > MAX_STEP_VIOLATION:
                success, status = False, f"infeasible point (violation {viol:.3g})"
        return SolveResult(
            success=success,
            status=status,
            iterations=int(stats.get("iter_count", 0)),
            solve_ms=ms,
            solver=kind,
            w=w,
            lam_x=np.asarray(sol["lam_x"]).ravel(),
            lam_g=np.asarray(sol["lam_g"]).ravel(),
            violation=viol,
        )

    def solve_converged(self, p: np.ndarray, w0: np.ndarray, lam_x0=None, lam_g0=None) -> SolveResult:
        """A converged IPOPT solve (cold, or primal-dual warm when multipliers are given)."""
        lbx, ubx = self.ocp.variable_bounds(p)
        bounds = {"lbx": lbx, "ubx": ubx}
        if self._ipopt_warm is None or lam_x0 is None or len(lam_x0) != self.ocp.n_w:
            return self._call(self._ipopt, "ipopt", p, w0, None, None, bounds)
        return self._call(self._ipopt_warm, "ipopt_warm", p, w0, lam_x0, lam_g0, bounds)

    # ------------------------------------------------------------------ SQP
    def rti(self, p: np.ndarray, w0: np.ndarray) -> SolveResult:
        """One RTI step from ``w0`` (its stage 0 is replaced by the parameters')."""
        t0 = time.perf_counter()
        with solver_call():
            out = self._rti(w0, p)
        self._last_step = (p.copy(), w0.copy(), out)
        w, viol = out[0], float(out[1][0])
        ms = 1e3 * (time.perf_counter() - t0)
        if not np.isfinite(viol) or not np.all(np.isfinite(w)):
            success, status = False, "non-finite step"
        elif viol > MAX_STEP_VIOLATION:
            success, status = False, f"infeasible step (violation {viol:.3g})"
        else:
            success, status = True, "step"
        return SolveResult(success, status, 1, ms, "rti", w, _NO_MULTIPLIERS, _NO_MULTIPLIERS, viol)

    def sqp(
        self, p: np.ndarray, w0: np.ndarray, max_iter: int | None = None, budget_ms: float | None = None
    ) -> SolveResult:
        """Gauss-Newton SQP from ``w0`` with a backtracking line search on the l1 merit function
        ``f + sigma |violation|_1`` (``sigma`` above the largest QP multiplier), at most
        ``max_iter`` iterations (default :data:`MAX_SQP_ITER`). Succeeds when the last point's
        violation is at most :data:`MAX_STEP_VIOLATION`; status 'converged' when the step and
        the violation are below the convergence tolerances.

        ``budget_ms``: no iteration is started that would, at the pace of the iterations so far,
        end after this many ms (the first always runs). For a loop paced by the wall clock: it
        makes the result depend on the machine's speed, so simulations leave it None.
        """
        iters = MAX_SQP_ITER if max_iter is None else max_iter
        t0 = time.perf_counter()
        w = np.asarray(w0, dtype=float)
        last = self._last_step
        reuse = last is not None and np.array_equal(last[0], p) and np.array_equal(last[1], w)
        x0 = self.ocp.initial_state(p)
        sigma, viol, status, it = 0.0, float("inf"), "iteration cap", 0
        with solver_call():
            for it in range(1, iters + 1):
                elapsed_ms = 1e3 * (time.perf_counter() - t0)
                if budget_ms is not None and it > 1 and elapsed_ms * it / (it - 1) > budget_ms:
                    status = f"time budget {budget_ms:.3g} ms"
                    it -= 1
                    break
                # The QP at w (the first one already solved by the failed RTI step, if so).
                step = last[2] if last is not None and reuse and it == 1 else self._rti(w, p)
                w_next, _violation, lam_max, f0, l1_0, slope = step
                w_lin = np.concatenate([x0, w[N_STATE:]])
                dw = w_next - w_lin
                if not (np.all(np.isfinite(dw)) and np.isfinite(lam_max[0])):
                    status = "non-finite QP step"
                    break
                sigma = max(sigma, _PENALTY_MARGIN * float(lam_max[0]))
                phi0 = float(f0[0]) + sigma * float(l1_0[0])
                # Directional derivative of the merit along a step that satisfies the linearised
                # constraints: the objective's slope minus the penalty of the removed violation.
                decrease = float(slope[0]) - sigma * float(l1_0[0])
                for trial in range(_MAX_LINE_SEARCH):  # the last trial is taken whatever its merit
                    alpha = _BACKTRACK**trial
                    w = w_lin + alpha * dw
                    f1, l1_1, viol = (float(v[0]) for v in self._merit(w, p))
                    if f1 + sigma * l1_1 <= phi0 + _ARMIJO * alpha * min(decrease, 0.0):
                        break
                if alpha * float(np.max(np.abs(dw))) < _SQP_STEP_TOL and viol < _SQP_VIOLATION_TOL:
                    status = "converged"
                    break
        ms = 1e3 * (time.perf_counter() - t0)
        success = bool(np.isfinite(viol) and viol <= MAX_STEP_VIOLATION and np.all(np.isfinite(w)))
        if not success and status != "non-finite QP step":
            status = f"infeasible after {it} SQP iterations (violation {viol:.3g})"
        return SolveResult(success, status, it, ms, "sqp", w, _NO_MULTIPLIERS, _NO_MULTIPLIERS, viol)

    def solve(self, p: np.ndarray, w0: np.ndarray, lam_x0=None, lam_g0=None) -> SolveResult:
        """One frame's solve with the configured scheme, warm-started at ``w0``."""
        if self.scheme == "rti":
            return self.rti(p, w0)
        if self.scheme == "sqp":
            return self.sqp(p, w0)
        return self.solve_converged(p, w0, lam_x0, lam_g0)
