"""Reports of recorded sessions: the paper's tables and figures from real measurements, on one HTML page.

``stereo-bench report SESSION [SESSION ...] [--out DIR]`` (see :mod:`stereo_bench.cli.report`) calls
:func:`stereo_bench.report.build.build_report`, which reads the sessions
(:mod:`~stereo_bench.report.collect`, with the rigorous model's prediction for every configuration, its
uncertainty budget and its structure per extrinsics source),
lays out the tables (:mod:`~stereo_bench.report.tables`), draws the figures
(:mod:`~stereo_bench.report.figures`) and annotated images (:mod:`~stereo_bench.report.annotate`) and
writes the page (:mod:`~stereo_bench.report.html`). See docs/REPORTS.md.

The submodules are imported on demand (matplotlib is loaded only when a report is built).
"""
