"""Vision pipeline, one module per stage: detect, calibrate, rectify, triangulate, measure; calibio for files."""
