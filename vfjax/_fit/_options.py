"""The options of a fit: the swarm's and the polish's settings, as objects."""

import equinox as eqx
import optimistix as optx


class Swarm(eqx.Module):
    """The global stage of a fit: a particle swarm (Clerc-Kennedy constriction by default),
    each iteration one batched simulation of every particle.

    Attributes:
        size: particles per fit.
        iterations: swarm iterations (0: polish from the starting model's values).
        chunk: iterations per compiled chunk; progress is reported between chunks.
        inertia: velocity inertia w.
        cognitive: pull towards a particle's own best, c1.
        social: pull towards the swarm's best, c2.
        max_speed: velocity clamp, as a fraction of each coordinate's range.
        boundary: "reflect" (mirror at the bound, velocity reversed) or "clip".
        cull_at: for a fit with restarts (independent swarms of one recording): the
            iteration after which the restarts lost in another regime stop, those whose
            swarm's best NMSE then exceeds ``cull_factor`` times the best of the
            recording's restarts; they end there, unpolished, and the others search on. 0,
            or at least ``iterations``: every restart searches to the end and is polished.
        cull_factor: how far behind the recording's best restart (a factor of NMSE) a
            restart is culled after ``cull_at`` iterations.
    """

    size: int = eqx.field(default=48, converter=int)
    iterations: int = eqx.field(default=60, converter=int)
    chunk: int = eqx.field(default=10, converter=int)
    inertia: float = eqx.field(default=0.7298, converter=float)
    cognitive: float = eqx.field(default=1.49618, converter=float)
    social: float = eqx.field(default=1.49618, converter=float)
    max_speed: float = eqx.field(default=0.25, converter=float)
    boundary: str = "reflect"
    cull_at: int = eqx.field(default=20, converter=int)
    cull_factor: float = eqx.field(default=10.0, converter=float)

    def __check_init__(self):
        if self.size < 1 or self.iterations < 0 or self.chunk < 1 or self.cull_at < 0:
            raise ValueError(
                "Swarm: size and chunk must be >= 1, iterations and cull_at >= 0, got "
                f"size={self.size}, iterations={self.iterations}, chunk={self.chunk}, "
                f"cull_at={self.cull_at}"
            )
        if not self.cull_factor >= 1.0:  # NaN refused too
            raise ValueError(f"Swarm: cull_factor must be >= 1, got {self.cull_factor}")
        if self.boundary not in ("reflect", "clip"):
            raise ValueError(f"Swarm: boundary must be 'reflect' or 'clip', got {self.boundary!r}")

    def to_dict(self) -> dict:
        """The fields by name (for JSON)."""
        return {f: getattr(self, f) for f in self.__dataclass_fields__}

    def program(self) -> "Swarm":
        """The settings that shape the compiled swarm (iterations, and where restarts are
        culled, run as data)."""
        return Swarm(
            self.size,
            0,
            self.chunk,
            self.inertia,
            self.cognitive,
            self.social,
            self.max_speed,
            self.boundary,
            0,
            1.0,
        )

    def culls(self, restarts: int) -> bool:
        """Whether a fit of ``restarts`` restarts culls them after `cull_at` iterations."""
        return restarts > 1 and 0 < self.cull_at < self.iterations


class Polish(eqx.Module):
    """The local stage of a fit: an optimistix least-squares solver run from the swarm's
    best point on the residual vector (forward-mode Jacobian through the simulator), keeping
    the best point it sees (`optimistix.BestSoFarLeastSquares`).

    Attributes:
        solver: an `optimistix.AbstractLeastSquaresSolver`; tolerances act on the O(1)
            search coordinates. Default: Levenberg-Marquardt, rtol 1e-6, atol 1e-9.
        max_steps: most solver steps.
    """

    solver: optx.AbstractLeastSquaresSolver = optx.LevenbergMarquardt(rtol=1e-6, atol=1e-9)
    max_steps: int = eqx.field(default=40, converter=int)

    def __check_init__(self):
        if self.max_steps < 1:
            raise ValueError(f"Polish: max_steps must be >= 1, got {self.max_steps}")
