"""The results pages of ``docs/results/``, one module per theme; ``make_docs.py`` writes them."""
