"""Scripts that redraw the figures of Dutta, Brotzakis & Mira (2018) from saved results.

Run from the repository root: ``python -m paper_figures.make_all`` (see ``README.md`` here).
"""
