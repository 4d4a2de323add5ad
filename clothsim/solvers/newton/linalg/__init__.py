"""Linear algebra of the Newton step, by job: the 3x3-block sparse (BSR) Hessian's pattern,
assembly and active-set projection (:mod:`.assembly`), the band Cholesky solver
(:mod:`.band`), the smoothers (:mod:`.smoothers`), the transfers between multigrid levels
(:mod:`.transfer`), the multigrid preconditioners (:mod:`.multigrid`) and the preconditioned
conjugate gradients they precondition (:mod:`.pcg`). Every name is re-exported here
(``from clothsim.solvers.newton.linalg import _assemble``).

The switches read here (coarsest_nodes, band_work, transpose_nodes, galerkin_terms,
trim_padding, panel_align, pad_identity, pair_smoothing) are fields of ``tuning.NewtonTuning``.

Shapes: n nodes, S springs, nb stored 3x3 blocks; vectors are flat (3n,) in node-major order
(x0, y0, z0, x1, ...). Units: stiffness blocks N/m, forces N, displacements m.
"""

from .assembly import (_assemble, _bsr_matvec, _bsr_pattern, _bsr_residual, _find_block,  # noqa: F401
                       _project_system, _projector_kinds)
from .band import (_band_cholesky_solve, _band_entry, _band_factor, _band_factored_solve,  # noqa: F401
                   _band_scatter_factor, band_order)
from .multigrid import (_GRID_LAYOUTS, _LAYOUTS, _SHARED_LOCK, LAYOUT_CACHE, _GridLayout,  # noqa: F401
                        _Level, _PaddedLayout, AlgebraicMultigrid, Multigrid, PaddedMultigrid,
                        _fill_empty_diagonal, _grid_layout, _pad_copy, _padded_layout)
from .pcg import _cg_direction, _cg_update, _dot, _pcg  # noqa: F401
from .smoothers import (_NO_MAP, _Transposed, _block6, _chain_gs, _gather_blocks, _i_lines,  # noqa: F401
                        _inv3s, _line_gs, _line_slots, _seam_smooth, _solve6,
                        _transposed_pattern, seam_chains)
from .transfer import (_Transfer, _coarse_row, _full_spans, _galerkin_pattern, _galerkin_sum,  # noqa: F401
                       _galerkin_terms, _galerkin_values, _grid_transfer, _line_parents,
                       _prolong_add, _restrict, _trimmed_spans, coarse_pairs)
