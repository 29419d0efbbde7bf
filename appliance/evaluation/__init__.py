"""Cores of the evaluation and benchmark commands and their shared figures."""
