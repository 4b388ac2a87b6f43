#!/usr/bin/env python
"""The drape test; the same as ``cloth-gym drape`` (see :mod:`cloth_gym.reports.drape`)."""

from cloth_gym.reports.drape import main

if __name__ == "__main__":
    main(prog="scripts/drape_test.py")
