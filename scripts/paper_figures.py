#!/usr/bin/env python
"""The paper's figures; the same as ``cloth-gym figures`` (see :mod:`cloth_gym.reports.figures`)."""

from cloth_gym.reports.figures import main

if __name__ == "__main__":
    main(prog="scripts/paper_figures.py")
