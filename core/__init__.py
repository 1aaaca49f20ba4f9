"""Code every part shares: the exception root, option-text parsers, atomic file writes and
the fixed-order numerics that keep lockstep runs byte-identical across CPUs.

It imports nothing else of ``swerve``.
"""
