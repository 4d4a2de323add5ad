"""Newton's tuning: every switch and constant that shapes the active-set Newton solver, in one
frozen record carried by ``NewtonOptions.tuning``.

The defaults are the solver's behaviour (every example's recorded equilibrium is reached with
them); a test or a benchmark that compares with another behaviour passes another record, e.g.
``NewtonOptions(tuning=replace(NewtonTuning(), hold_fit=False))``. The measurements behind each
default are in docs/benchmarks*.md (the names there are the former module constants, upper case).
numba kernels get the plain values, never the record.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass


class Curvature(enum.IntEnum):
    """How the contact's curvature term -lam S enters the Hessian on a smooth surface."""

    OFF = 0
    """Not at all."""
    POSITIVE = 1
    """Its positive semi-definite part only (the model is then too stiff along the surface)."""
    FULL = 2
    """All of it (the Hessian may be indefinite: Newton can converge to a saddle)."""
    FULL_WHILE_DEFINITE = 3
    """All of it while the projected system with it is positive definite, else its positive part
    (exact Newton where the model has a minimum, the descent elsewhere)."""


@dataclass(frozen=True)
class NewtonTuning:
    """Newton's switches and constants (defaults: the solver's behaviour)."""

    # --- the linear solve (iteration.py, linalg/)
    direct_dofs: int = 6000
    """Systems with at most this many unknowns are factorised directly (no multigrid) [unknowns]."""
    band_work: float = 1.2e7
    """A direct system uses the banded Cholesky when (3n) x b^2 is at most this, else the sparse LU
    [unknowns x unknowns^2] (b: half-bandwidth after reordering)."""
    band_on_smooth: bool = True
    """The banded Cholesky also on the smooth surface of a mesh (no example's equilibrium uses it)."""
    forcing_max: float = 1e-1
    """Largest forcing term (relative residual of the inexact linear solve) [1]."""
    iterate_budget_cg: int = 400
    """CG iterations after which an iteration stops retrying with larger Levenberg shifts
    [iterations]; a work budget so that the path does not depend on the machine's load."""
    blocked_warm_start: bool = True
    """After blocking constraints were added, CG restarts from the previous step projected onto the
    new active set (a local correction)."""
    blocked_reuse_mg: bool = False
    """... with the multigrid built for the previous active set when that start misses the forcing
    term (False: rebuilt for the new set)."""
    coarsest_nodes: int = 400
    """Multigrid: stop coarsening at this many nodes [nodes]."""
    transpose_nodes: int = 8000
    """Levels with at least this many nodes sweep their i lines on a line-by-line renumbered copy
    of the matrix [nodes] (half the sweep time on 201^2)."""
    galerkin_terms: bool = True
    """Galerkin coarse operators from terms made once per pattern (the same blocks bit for bit in
    a third of the time; False: the direct product)."""
    trim_padding: bool = True
    """PaddedMultigrid's smoother lines leave out the padding at their ends (same V-cycle, fewer
    nodes swept)."""
    panel_align: int = 4
    """PaddedMultigrid's panels start on columns that are multiples of this [columns] (4: a panel's
    first column is a node of the two first coarse levels)."""
    pad_identity: bool = True
    """The padding of PaddedMultigrid's rectangle gets identity blocks (exact Galerkin products;
    False: a scaled identity)."""
    pair_smoothing: bool = True
    """Sewn pairs relaxed jointly in PaddedMultigrid's smoother (False: the line smoother alone)."""

    # --- the step, its line search and acceptance (iteration.py)
    energy_resolution: float = 1e-13
    """Relative energy change below which the energy cannot tell two states apart [1] (float64)."""
    trapezoid_energy: bool = True
    """A trial below the energy's resolution is judged by the trapezoid rule's energy change
    -1/2 (F0 + F1).(x1 - x0) against Armijo (exact for a quadratic energy)."""
    hold_entering: bool = True
    """Released nodes on the surface whose step enters the mold are held on it (_block_entering);
    False only to compare with the solver before it."""
    hold_share: float = 0.0
    """... when their moves carry more than this share of the step's predicted energy decrease [1]
    (0: always, the projected Newton rule; 1 let nodes with a zero multiplier churn)."""
    scan_rules_on_facets: bool = True
    """hold_share and kink_decay also on a faceted mesh (not only on its smooth surface): the
    faceted torso bands 36-115 -> 29-59 iterations."""
    hold_share_everywhere: bool = True
    """hold_share on the analytic molds too (the 225-across circle: 5-6 fine iterations -> 3)."""
    lm_alpha_low: float = 0.1
    """The Levenberg shift is raised tenfold after a step the line search cut below this length [1]."""
    lm_alpha_high: float = 1.0
    """... and lowered after a step of at least this length [1] (0.5-0.6 took more iterations)."""
    lm_max: float = 1e4
    """Largest Levenberg shift, relative to the mean diagonal [1]."""
    curvature: Curvature = Curvature.FULL_WHILE_DEFINITE
    """The contact's curvature term on a smooth surface (see Curvature)."""
    curvature_cg_test: int = 5
    """FULL_WHILE_DEFINITE on levels solved by CG: LOBPCG iterations estimating the smallest
    eigenvalue [iterations] (0: the positive part always; the stocking 209 -> 50 iterations)."""
    kink_decay: float = 10.0
    """On a mesh's smooth surface the slack springs' kink stiffness is divided by this after every
    full step that kept the contact set [1] (the kink is a stiffness the energy does not have)."""
    kink_floor: float = 1e-4
    """... down to this share of its value [1]."""
    line_search_records: bool = True
    """On the smooth surface, each free node's segment is traced once per line search and the
    accepted step's mold answers come from its trial pass."""
    neg_curv_move: float = 0.8
    """Near a saddle on a direct level the step also moves along the negative-curvature direction,
    its largest coordinate move this many lattice spacings [1] (0: off; smooth campaign 744 -> 718
    iterations)."""
    neg_curv_iters: int = 5
    """LOBPCG iterations for that direction [iterations]."""

    # --- contact projections (active_set.py; passed to its kernels as plain values)
    release_gap: float = 1e-12
    """A contact node moved farther than this off the surface may leave it [m]."""
    smooth_foot_trusted: bool = True
    """A node projected onto a converged foot point of the smooth surface is not queried again."""
    fixed_projection_steps: int = 6
    """Newton steps along the free part of the normal that bring a contact node with held axes out
    of the mold after its projection [steps] (0: none, the solver before them)."""
    fixed_projection_everywhere: bool = True
    """... on every mold, not only a mesh's smooth surface; False only to compare with the solver
    before it."""
    fixed_projection_tol: float = 1e-14
    """... until the node is within this of the surface [m]."""
    held_keep_gap: bool = True
    """A contact node held while still off the surface closes its gap in the step (a prescribed
    normal move) instead of being projected; False only to compare with the solver before it."""
    held_gap_min: float = 1e-12
    """... when the gap exceeds this [m] (rounding-error gaps are projected as before)."""

    # --- grid sequencing (sequencing.py, rim.py, settle.py)
    coarsest_rel: float = 1e-2
    """The coarsest grid is solved to 1e-8 of its start residual, or to this share once an
    iteration keeps its contact set [1] (201^2 cap: 3 iterations instead of 5)."""
    level_rel: float = 1e-1
    """The levels between the coarsest and the last are solved to this share of their start
    residual [1]."""
    mid_level_iterations: int | None = 1
    """... taking at most this many Newton iterations [iterations] (None: no cap)."""
    cut_coarsest_nodes: int = 100
    """A cut lattice's sequencing goes down to grids of this many nodes [nodes] (a full lattice's
    stops at coarsest_nodes)."""
    rim_sweeps: int = 4
    """Jacobi sweeps relaxing the fringe of an interpolated start [sweeps]."""
    settle_rim: bool = True
    """A cut lattice's outline band of an interpolated start is settled node by node
    (rim.settle_outline); False only to compare with the solver before it."""
    rim_band: int = 6
    """... the band: rows from a held node or a node missing a lattice neighbour [lattice hops]."""
    rim_gs_sweeps: int = 6
    """... symmetric Gauss-Seidel sweeps over it [sweeps]."""
    settle_contact_rim: bool = True
    """Every interpolated start has its contact rim settled node by node (settle.settle_start)."""
    settle_width: int = 3
    """... the band around the contact rim [lattice hops]."""
    settle_sweeps: int = 8
    """... sweeps at most [sweeps]."""
    hold_fit: bool = True
    """A cut lattice's guessed holds are placed where the sheet puts them (_HoldFit; 225-across
    circle: fine start 5.3e-3 -> 1.2e-3 N); False: the flat guesses."""
    hold_fit_neighbours: int = 4
    """... each fit from this many nearest free nodes [nodes]."""
    hold_fit_reach: float = 3.0
    """... lying within this many of the level's spacings [1]."""
    hold_refit_coarsest: int = 1
    """... refitted this many times on the coarsest grid after a first solve [refits]."""
    hold_first_rel: float = 1e-2
    """The coarsest grid's first solve (before its refit) goes to this share of its start residual [1]."""
    hold_refit_rel: float = 1e-1
    """... and its solve after the refit to this share [1]."""
    hold_band: bool = True
    """The last coarse level is solved again after its holds are placed at their fine nodes' places."""

    def __post_init__(self):
        object.__setattr__(self, "curvature", Curvature(self.curvature))


@dataclass(frozen=True)
class FrictionTuning:
    """The frictional load steps' switches and constants (``friction.solve_steps``; defaults: its
    behaviour, measured in docs/method/friction.md, Candidates measured)."""

    max_relags: int = 40
    """Solves of one load step with the friction refreshed before the step counts as failed [solves]."""
    refresh_every_iteration: bool = True
    """The friction's normal forces and tangent planes refreshed before every Newton iteration
    (True) or once per solve (False: each solve keeps one frozen friction)."""
    refresh_forcing: float = 0.1
    """With refreshes once per solve: a refresh's solve stops at this share of the residual it
    starts from (or at e, the last one) [1]."""
    rescue_after: int = 40
    """Newton iterations of a load step's first solve before it starts again with a wider slip
    eps (0: never) [iterations]."""
    eps_continuation: float = 10.0
    """The rescue's slip eps over the scene's: the step solved with it from its start, then
    with the scene's eps from there (1: no rescue) [1]."""
    max_cuts: int = 8
    """Halvings of one load step in a row before the sequence ends [cuts]."""

    def __post_init__(self):
        if isinstance(self.max_relags, bool) or int(self.max_relags) != self.max_relags or self.max_relags < 1:
            raise ValueError(f"FrictionTuning.max_relags must be a whole number >= 1 (got {self.max_relags!r})")
        if isinstance(self.max_cuts, bool) or int(self.max_cuts) != self.max_cuts or self.max_cuts < 0:
            raise ValueError(f"FrictionTuning.max_cuts must be a whole number >= 0 (got {self.max_cuts!r})")
        if isinstance(self.rescue_after, bool) or int(self.rescue_after) != self.rescue_after or self.rescue_after < 0:
            raise ValueError(f"FrictionTuning.rescue_after must be a whole number >= 0 (got {self.rescue_after!r})")
        if not float(self.eps_continuation) >= 1.0:
            raise ValueError(f"FrictionTuning.eps_continuation must be >= 1 (got {self.eps_continuation!r})")
        if not 0.0 < float(self.refresh_forcing) < 1.0:
            raise ValueError(f"FrictionTuning.refresh_forcing must lie in (0, 1) (got {self.refresh_forcing!r})")
        object.__setattr__(self, "refresh_every_iteration", bool(self.refresh_every_iteration))


__all__ = ["NewtonTuning", "FrictionTuning", "Curvature"]
