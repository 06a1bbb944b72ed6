"""The CodeActionBench task suite."""
