"""Simulators that implement the real interfaces: a rendered stereo camera pair and a GRBL emulator."""
