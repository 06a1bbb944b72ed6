"""Render-device diagnostics for SAPIEN: what Vulkan driver is installed, and why none works.

SAPIEN 3 renders through Vulkan. On a CPU-only machine that means Mesa's lavapipe (llvmpipe), and
only Mesa >= 24.3 exposes what SAPIEN needs (``descriptorBindingPartiallyBound``); Debian 12's own
Mesa 22.3 does not, and SAPIEN then says only "failed to find a rendering device". The functions here
turn that into a diagnosis with the command that fixes it. Nothing here imports SAPIEN.
"""
from __future__ import annotations

import ctypes
import ctypes.util
import glob
import json
import os
import re
from functools import cache, lru_cache
from pathlib import Path

MIN_MESA = (24, 3)
ICD_DIRS = ("/usr/share/vulkan/icd.d", "/etc/vulkan/icd.d", "/usr/local/share/vulkan/icd.d")
LIB_DIRS = ("/usr/lib/x86_64-linux-gnu", "/usr/lib/aarch64-linux-gnu", "/usr/lib64", "/usr/lib",
            "/usr/local/lib")
FIX = ("install mesa-vulkan-drivers >= 24.3 from bookworm-backports: "
       "echo 'deb http://deb.debian.org/debian bookworm-backports main' | "
       "sudo tee /etc/apt/sources.list.d/backports.list && sudo apt-get update && "
       "sudo apt-get install -y -t bookworm-backports mesa-vulkan-drivers "
       "(on other systems: any Mesa >= 24.3 lavapipe, or a GPU with its Vulkan driver); "
       "or build the simulator with render: false for physics-only use")


def icd_files() -> list[str]:
    """Vulkan ICD manifests the loader would consider (honours VK_ICD_FILENAMES / VK_DRIVER_FILES)."""
    forced = os.environ.get("VK_DRIVER_FILES") or os.environ.get("VK_ICD_FILENAMES")
    if forced:
        return [p for p in forced.split(os.pathsep) if p]
    out: list[str] = []
    for d in ICD_DIRS:
        out += sorted(glob.glob(os.path.join(d, "*.json")))
    return sorted(set(os.path.realpath(p) for p in out))


def _icd_library(manifest: str) -> str | None:
    try:
        lib = json.loads(Path(manifest).read_text())["ICD"]["library_path"]
    except (OSError, ValueError, KeyError, TypeError):
        return None
    if os.path.isabs(lib):
        return lib if os.path.exists(lib) else None
    for d in LIB_DIRS:
        p = os.path.join(d, lib)
        if os.path.exists(p):
            return p
    return None


@cache
def _version_in_library(path: str) -> str | None:
    """The "Mesa X.Y.Z..." string compiled into a Mesa driver library (a fast byte scan)."""
    try:
        data = Path(path).read_bytes()
    except OSError:
        return None
    m = re.search(rb"Mesa (\d+\.\d+\.\d+[0-9A-Za-z.~+\-]*)", data)
    return m.group(1).decode() if m else None


@lru_cache(maxsize=1)
def lavapipe() -> dict[str, str | None]:
    """{"manifest", "library", "mesa"} of the installed lavapipe driver (values None if absent)."""
    for manifest in icd_files():
        if "lvp" in os.path.basename(manifest):
            lib = _icd_library(manifest)
            return {"manifest": manifest, "library": lib, "mesa": _version_in_library(lib) if lib else None}
    return {"manifest": None, "library": None, "mesa": None}


def preload() -> list[str]:
    """Load, without creating an instance or a device, the Vulkan loader SAPIEN uses and the Mesa
    drivers (``libvulkan_*``, lavapipe among them) of the manifests the loader would read. Called in a
    sweep's fork server (``cab_sim_sapien.cab_preload``) so that its workers share these libraries
    and the relocations of the LLVM they link, instead of each writing its own (tens of MiB). Other
    vendors' drivers are left to the worker (they may talk to a device when loaded). Returns the
    libraries loaded; one that does not load is left out (the worker reports it when it renders)."""
    wanted = [os.environ.get("SAPIEN_VULKAN_LIBRARY_PATH") or "libvulkan.so.1"]
    for manifest in icd_files():
        lib = _icd_library(manifest)
        if lib and os.path.basename(lib).startswith("libvulkan_"):
            wanted.append(lib)
    loaded = []
    for lib in dict.fromkeys(wanted):
        try:
            ctypes.CDLL(lib)
        except OSError:
            continue
        loaded.append(lib)
    return loaded


def mesa_version_tuple(version: str | None) -> tuple[int, int] | None:
    if not version:
        return None
    m = re.match(r"(\d+)\.(\d+)", version)
    return (int(m.group(1)), int(m.group(2))) if m else None


def diagnose(error: BaseException | str) -> str:
    """A one-paragraph diagnosis of a failed render-device start, ending with the fix."""
    parts = [f"SAPIEN could not start a Vulkan render device ({error})."]
    loader = ctypes.util.find_library("vulkan")
    if not loader:
        parts.append("The Vulkan loader (libvulkan.so.1, Debian package libvulkan1) is not installed.")
    forced = os.environ.get("VK_DRIVER_FILES") or os.environ.get("VK_ICD_FILENAMES")
    icds = icd_files()
    if forced:
        missing = [p for p in icds if not os.path.exists(p)]
        parts.append(f"VK_ICD_FILENAMES/VK_DRIVER_FILES restricts drivers to {icds}"
                     + (f"; missing: {missing}." if missing else "."))
    elif not icds:
        parts.append("No Vulkan driver manifests were found in " + ", ".join(ICD_DIRS) + ".")
    else:
        parts.append("Vulkan drivers found: " + ", ".join(os.path.basename(p) for p in icds) + ".")
    lvp = lavapipe()
    if lvp["manifest"] is None:
        if forced:
            parts.append("Mesa's CPU driver lavapipe (lvp_icd) is not among them: unset the variable "
                         "or point it at lvp_icd.*.json.")
        else:
            parts.append("Mesa's CPU driver lavapipe (lvp_icd) is not installed.")
    else:
        mesa = lvp["mesa"]
        vt = mesa_version_tuple(mesa)
        if vt is not None and vt < MIN_MESA:
            parts.append(f"lavapipe is Mesa {mesa}, too old: SAPIEN 3 needs Mesa >= "
                         f"{MIN_MESA[0]}.{MIN_MESA[1]} (descriptorBindingPartiallyBound).")
        elif mesa:
            parts.append(f"lavapipe is Mesa {mesa}, recent enough; check `vulkaninfo --summary` "
                         f"(package vulkan-tools) for the device it reports.")
        else:
            parts.append("lavapipe is installed but its Mesa version could not be read.")
    parts.append("Fix: " + FIX + ".")
    return " ".join(parts)


def describe_device(device_name: str | None) -> dict[str, str]:
    """Provenance fields for a started device: name, driver, Mesa and Vulkan versions if known."""
    out: dict[str, str] = {}
    if device_name:
        out["render_device"] = device_name
    if device_name and "llvmpipe" in device_name.lower():
        lvp = lavapipe()
        out["render_driver"] = "lavapipe (Mesa llvmpipe, CPU)"
        if lvp["mesa"]:
            out["mesa"] = lvp["mesa"]
        if lvp["manifest"]:
            try:
                out["vulkan_api"] = json.loads(Path(lvp["manifest"]).read_text())["ICD"]["api_version"]
            except (OSError, ValueError, KeyError):
                pass
    elif device_name:
        out["render_driver"] = "gpu"
    return out


def use_shader_cache(folder: Path) -> str:
    """Point Mesa's on-disk shader cache at ``folder`` unless ``MESA_SHADER_CACHE_DIR`` is set;
    returns the folder in use. Must run before the first Vulkan device of the process is created.

    lavapipe compiles SAPIEN's pipelines with LLVM in every process (0.75 s of an attempt's set-up on
    a 2-core machine); with the cache the compiled shaders are read back (0.5 s -> the set-up of an
    idle attempt drops from 1.25 s to 0.5 s). Mesa keys each entry by the driver's build and the
    shader's own hash, so an entry from another driver or shader is never used."""
    current = os.environ.get("MESA_SHADER_CACHE_DIR")
    if current:
        return current
    folder.mkdir(parents=True, exist_ok=True)
    os.environ["MESA_SHADER_CACHE_DIR"] = str(folder)
    return str(folder)
