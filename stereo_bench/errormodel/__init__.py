"""Error models of the stereo bench (see docs/ERROR_MODEL.md).

- :mod:`~stereo_bench.errormodel.paper`: the paper's model exactly as published (e1, e2, γ, optimum K).
- :mod:`~stereo_bench.errormodel.rigorous`: first-order propagation of image noise through the real
  triangulation to every corner, the measured square and the board centre, for any rig and board
  pose; structural sensitivities; feasibility.
- :mod:`~stereo_bench.errormodel.montecarlo`: the Monte Carlo that checks the first-order figures.
- :mod:`~stereo_bench.errormodel.surfaces`: sweeps over (B, Z) and α, optimum search, and the computed
  comparison with the paper's claims.
- :mod:`~stereo_bench.errormodel.rig`: what the rig and boards add (the budget's structure and target terms).
- :mod:`~stereo_bench.errormodel.advisor`: B and α ranges that meet an error target.

The submodules are imported on demand (``from stereo_bench.errormodel import paper``).
"""
