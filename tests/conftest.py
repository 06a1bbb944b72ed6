# cab_core first: it pins the numerics (cab_core.numerics) before anything imports numpy, so the tests
# run with the settings every attempt process has.
import cab_core  # noqa: F401
