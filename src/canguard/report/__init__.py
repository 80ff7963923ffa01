"""Summaries, progress and plots of a run."""
