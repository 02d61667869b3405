"""Checks shared by every package (:mod:`checks.arrays`), below ``matching`` and ``surface``."""
