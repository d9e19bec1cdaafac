"""Hardware access for stereo-bench: cameras, the rig controller, simulators and replay.

This package knows bytes, frames and devices. It never does measurement math; the measurement code
in ``stereo_bench`` sees it only through the small protocols each subpackage defines.
"""
