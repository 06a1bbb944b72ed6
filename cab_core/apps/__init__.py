"""The command-line programs: ``cab`` and its command-line checks, ``cab-bench``,
``cab-suite-check``, ``cab-gallery``, ``cab-bench-sweep``."""
