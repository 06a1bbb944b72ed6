"""Analyses of attempt records: checkpoints now; metrics, failure stages and reports later."""
