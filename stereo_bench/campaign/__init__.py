"""Campaigns: a validated config (TOML), its plan as data, and the runner that executes it."""
