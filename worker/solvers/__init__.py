"""The solver core: settings and result, one measurement layout, the methods, the point engine.

``simulate.py`` (one level up) is the public door; this package is what it dispatches to.
"""
