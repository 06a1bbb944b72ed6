"""How the supervisor and a child process that runs attempts speak: the child's exit statuses and
the environment variable naming its supervisor (a child whose supervisor is gone exits)."""

EXIT_FAULT = 1  # the attempt's process failed (crash, unexpected exception): retried as infrastructure
EXIT_CONFIG = 2  # the configuration is wrong: never retried
EXIT_RENDERER = 3  # no renderer on this machine: never retried
PARENT_ENV = "CAB_SUPERVISOR_PID"
