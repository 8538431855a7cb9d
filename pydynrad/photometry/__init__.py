"""Light as lighting people measure it: photometric units.

See docs/design.md, 'Units and photometry'.
"""
