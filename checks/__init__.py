"""Checks and robust statistics shared by every package (:mod:`checks.arrays`,
:mod:`checks.robust`), below ``matching`` and ``surface``."""
