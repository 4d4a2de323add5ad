"""Active-set Newton on the strain energy, with a multigrid-preconditioned CG and grid sequencing.

The equilibrium the paper's relaxation seeks (eq. 6: every free node's resultant zero, contact
nodes' resultant inside the cone of their mold normals) is the constrained minimum of the total
potential energy E(x) = sum over springs of w l0 int_0^strain T(s) ds minus the external work.
E is C1 and piecewise quadratic in the strain, so Newton's method on it converges quickly once the
set of contact nodes and of taut/slack springs has settled. One iteration:

1. Active set: each contact node's resultant R (constrained axes removed) is projected onto the
   cone of its feature's face normals (contact.cone_distance's geometry). A node whose R points
   out of the mold (projection = origin, i.e. n.R > 0 on a face) is released; otherwise the
   normals carrying a positive multiplier become constraints. With the constrained axes they
   define a per-node projector Pi_k onto the directions the node may move in (3 for a free node,
   2 on a face: the tangent plane, 1 along a concave edge, 0 in a corner). A node pressed onto a
   convex edge or vertex of a mesh (R inside the cone of several normals) satisfies eq. 6 but is
   not at an energy minimum: it keeps only the face it slides down (``_ridge_face``).
   After the linear solve, a node on an edge or vertex whose step would leave the feature's
   tangent cone through an inactive face (into a groove's other face) gets that face's normal
   added and the system is solved again (``_block_infeasible``, blocking constraints): otherwise
   the projection back onto the surface bends the path at first order and no step length lowers
   the energy (the stall on the torso mesh). Likewise a released node still on the surface whose
   coupled step moves it into the mold is held on it (``_block_entering``) when, without its
   move, the step would not lower the energy at first order (the stalls on scanned bodies); on
   the smooth surface of a mesh always (``NewtonTuning.hold_share``: otherwise nodes whose
   multiplier is about 0 churn in and out of contact), where the slack springs' kink also decays
   after full steps (``NewtonTuning.kink_decay``) and held-axis contact nodes are projected onto the
   curved surface along their free axes (``NewtonTuning.fixed_projection_steps``). A node held while
   still a little off the surface closes its gap in the step (``NewtonTuning.held_keep_gap``). The mold's
   answers at the nodes are queried once per set of positions (``active_set._query_nodes``).
2. Linear system: (Pi K Pi + mu Pi + (I - Pi)) dx = Pi f, where K = d^2E/dx^2 is assembled from
   ``kernels.spring_hessian_block`` (transverse term clamped >= 0 so K is positive semi-definite;
   at and below strain 0 the first segment's slope times ``NewtonOptions.kink`` (default 1e-3)
   replaces the zero stiffness of a slack spring: this only shapes the direction, never the
   forces) and mu is a Levenberg shift (relative to the mean diagonal) raised when a step fails.
   Solved by conjugate gradients preconditioned with a geometric multigrid V-cycle: bilinear
   prolongation on the structured node grid (projected by Pi on the finest level), Galerkin
   coarse operators, symmetric 3x3-block Gauss-Seidel smoothing, a sparse LU (scipy ``splu``) on
   the coarsest grid. Small problems (<= ``NewtonTuning.direct_dofs`` unknowns) are factorised directly (on a
   triangle-mesh mold a narrow band by a banded Cholesky in reverse Cuthill-McKee order,
   ``linalg._band_cholesky_solve``; otherwise, or when a pivot is not positive, the sparse LU).
   A system the sparse LU finds exactly singular (a direction without stiffness under a shift below
   the pivots' rounding) gives no step: the Levenberg shift is raised, and when no shift helps the
   iteration reports ``StepStatus.NO_PROGRESS`` with the reason (``NewtonLevel.failure``, in the
   run's message); the coarsest multigrid grid's LU is retried with larger diagonal shifts, then
   replaced by its diagonal (``linalg.multigrid._coarse_solver``).
   On the smooth surface of a mesh K also holds the contact's curvature term -lam S, all of it
   while the system stays positive definite and its positive part otherwise
   (``NewtonTuning.curvature``, a ``Curvature`` mode); where it is indefinite on a direct level the step also moves along
   its direction of negative curvature (LOBPCG's smallest eigenvector, ``NewtonTuning.neg_curv_move``),
   so that Newton leaves a saddle at once instead of creeping away from it.
3. Line search on the energy along x + a dx with the paper's contact rules applied to every
   trial: a free node's move is clipped where it would enter the mold (``contact.stop_at_surface``) and
   it becomes a contact node; contact nodes are projected back onto the surface
   (``mold_query``); no node ever ends inside. A contact node carried past a convex edge or
   vertex into free space (its closest point is that edge or vertex and its resultant pulls it
   away from it) becomes free instead of being pulled back onto the ridge (a node pulled over a
   box's edge). On a mesh mold, when the straight trial fails, the same step with contact nodes
   stopped at their face's border (so a node whose equilibrium is on an edge lands on it) is
   tried too. On the smooth surface a free node's segment is traced once per line search (the
   shorter steps' segments are its prefixes) and the accepted step's mold answers come from its
   trial pass (``NewtonTuning.line_search_records``). Backtracking (Armijo, halving). When the energy
   difference is below float64 resolution (close to the solution) the step is accepted if it
   lowers the residual instead, or if the trapezoid rule's energy change -1/2 (F0 + F1).(x1 - x0)
   meets the Armijo rule (``NewtonTuning.trapezoid_energy``); when none holds even with a large Levenberg shift,
   the step reports ``StepStatus.NO_PROGRESS`` (run status ``stalled``), keeping the best state.
4. Grid sequencing (``NewtonOptions.sequencing``): when the grid's divisions are even and large, the
   scene is first solved on the grid with every second node (recursively), and the result is
   interpolated bilinearly and projected onto the mold as the starting point. The coarse solves
   are one recorded iteration. Cut and multi-panel lattices sequence too (every panel with even
   divisions; warp, weft and seam-pair springs only): ``Topology.coarsen`` keeps every second
   node, the coarse springs carry the fine band widths summed over their band
   (``grid._coarsen_lattice``), the interpolation renormalises over the coarse corners that exist
   (``Topology.lattice_prolongation``) and the outline's fringe is relaxed after it.

References:
- Nocedal J., Wright S., Numerical Optimization, 2nd ed., Springer 2006 (line search Newton,
  Armijo condition, Levenberg-Marquardt shift, inexact Newton forcing terms).
- Briggs W., Henson V. E., McCormick S., A Multigrid Tutorial, 2nd ed., SIAM 2000 (V-cycle,
  Galerkin coarse operators, nested iteration = grid sequencing).
- Hestenes M., Stiefel E., Methods of conjugate gradients for solving linear systems, J. Res.
  NBS 49, 1952 (preconditioned CG).
- Garcia M., Gomez M., Ruiz O., Boulanger P., "Spring-particle model for hyperelastic cloth",
  Dyna 74 (151), 2007 (the model, the residual eq. 6 and the contact rules reproduced here).

Limitations:
- The mold's curvature is not in the Hessian (contact nodes move in the tangent plane and are
  projected back), so on strongly curved molds convergence is fast-linear rather than quadratic.
- Slack regions have no unique equilibrium; Newton stops at one of them (see Result
  .undetermined_nodes()). Near springs that end exactly at strain 0 the residual can chatter;
  the residual-based acceptance keeps it converging but a few extra iterations may be needed.
- The geometric multigrid needs one full warp/weft rectangle; cut or multi-panel lattices are
  laid in a padded rectangle (PaddedMultigrid; seams relaxed by 6x6-block line solves along
  them), or use PyAMG's smoothed aggregation (AlgebraicMultigrid, slower). The coarse spaces
  ignore the mold, so the CG iteration count grows slowly on grids with many contact nodes.
- Grid sequencing needs even divisions; otherwise it starts directly on the fine grid. On cut
  lattices it also skips models with shear or bending springs or seam elements (unequal node
  counts), which the coarse model does not carry.

Every switch and constant of the method is a field of ``clothsim.solvers.tuning.NewtonTuning``,
carried by ``NewtonOptions.tuning`` (defaults: the behaviour described here).

Layout (one module per job): ``linalg`` (BSR pattern and assembly, multigrid, PCG),
``active_set`` (projectors, ridge faces, blocking constraints, trial positions at the surface),
``iteration`` (``NewtonLevel``: the step, line search, acceptance), ``sequencing`` (coarse grids,
prolongation, ``grid_sequence``), ``settle`` (the contact rim of an interpolated start settled
node by node; the node's spring block both settlements use), ``rim`` (a cut lattice's outline band
of an interpolated start settled node by node), ``solver`` (``NewtonSolver`` and the settings wrapper ``solve``).
"""

# the private kernels are re-exported for the tests that drive one step by hand
from .active_set import PENETRATION_TOL, _apply_pi, _block_entering, _block_infeasible, _projectors, _trial_positions  # noqa: F401
from .iteration import NewtonLevel
from .linalg import Multigrid, _assemble, _bsr_matvec, _bsr_pattern, _pcg, _project_system  # noqa: F401
from .sequencing import coarsen_model, grid_sequence, prolong_state, sequencing_chain
from .solver import STALL_NEWTON, NewtonSolver, solve
from ..tuning import Curvature, NewtonTuning

__all__ = ["NewtonSolver", "solve", "STALL_NEWTON", "NewtonLevel", "Multigrid", "coarsen_model",
           "prolong_state", "sequencing_chain", "grid_sequence", "PENETRATION_TOL", "NewtonTuning", "Curvature"]
