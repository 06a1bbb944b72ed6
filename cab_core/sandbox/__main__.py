"""``python -m cab_core.sandbox [auto|required]``: which confinement this machine gives run_code, and
how fast it is (spawn, one tool RPC round trip, one 640x480 load_image)."""
from __future__ import annotations

import statistics
import sys
import time

import numpy as np

from cab_core.sandbox import DispatchResult, Sandbox, SandboxConfig, SandboxUnavailable


def main(argv: list[str]) -> int:
    mode = argv[0] if argv else "auto"
    image = np.zeros((480, 640, 3), np.uint8)
    try:
        t0 = time.perf_counter()
        sandbox = Sandbox(["ping"], lambda name, kwargs: DispatchResult({"pong": kwargs.get("i")}),
                          lambda obs_id: image, SandboxConfig(mode=mode, max_internal_calls=100_000))
        first = time.perf_counter() - t0
    except SandboxUnavailable as exc:
        print(f"unavailable: {exc}")
        return 1
    with sandbox:
        print(f"confinement: {sandbox.confinement}")
        for layer, state in sandbox.confinement_layers.items():
            print(f"  {layer}: {state}")
        if sandbox.confinement_note:
            print(f"note: {sandbox.confinement_note}")
        assert sandbox.spawn_s is not None, "set when the child started"
        print(f"spawn: {sandbox.spawn_s * 1e3:.0f} ms (first Sandbox() call {first * 1e3:.0f} ms)")
        sandbox.run("pass")
        per_call = []
        for _ in range(5):
            t0 = time.perf_counter()
            result = sandbox.run("for i in range(2000):\n    ping(i=i)")
            assert result["ok"], result["error"]
            per_call.append((time.perf_counter() - t0) / 2000)
        print(f"tool RPC round trip: {statistics.median(per_call) * 1e3:.3f} ms median of 5 x 2000 calls "
              f"(min {min(per_call) * 1e3:.3f} ms)")
        t0 = time.perf_counter()
        result = sandbox.run("for i in range(100):\n    a = load_image('o')")
        print(f"load_image 640x480x3: {(time.perf_counter() - t0) / 100 * 1e3:.3f} ms")
        t0 = time.perf_counter()
        sandbox.run("pass")
        print(f"empty program: {(time.perf_counter() - t0) * 1e3:.3f} ms")
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv[1:]))
