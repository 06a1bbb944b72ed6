"""cab-studio: a local web application over a tree of attempt records (progress of sweeps, their
reports, each attempt's page) where a person can also play an attempt. See docs/studio.md."""
