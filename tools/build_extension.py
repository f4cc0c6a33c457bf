"""Build the extension zips into dist/: fetch the wheels the manifest lists, then bl_pkg build.

Usage: python tools/build_extension.py [--output-dir dist]   (exits non-zero on failure)
"""
import argparse
import subprocess
import sys
import tomllib
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def manifest(root=ROOT):
    with open(root / "blender_manifest.toml", "rb") as fh:
        return tomllib.load(fh)


def download_wheels(root=ROOT):
    """Fetch every wheel the manifest lists that is not in wheels/ yet."""
    for rel in manifest(root).get("wheels", []):
        path = (root / rel).resolve()
        if path.exists():
            continue
        # name-version-pyver-abi-platform.whl; a platform may be a dotted set of tags.
        name, version, pyver, _abi, plat = path.stem.split("-")
        cmd = [sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary=:all:",
               "--python-version", pyver.removeprefix("cp"), "-d", str(path.parent),
               f"{name}=={version}"]
        for tag in plat.split("."):
            cmd += ["--platform", tag]
        subprocess.run(cmd, check=True)
        if not path.exists():  # PyPI served a differently named file: fix the manifest.
            raise RuntimeError(f"pip did not produce {path.name}")


def bl_extension(args):
    """Run a `blender --command extension` subcommand; returns its exit code."""
    import bpy  # noqa: F401  (puts bl_pkg from bpy's addons_core on sys.path)
    from bl_pkg import bl_extension_cli
    return bl_extension_cli.cli_extension_handler(list(args))


def this_platform():
    """Blender's name for this machine, e.g. 'linux-x64', as used in split zip names."""
    import bpy  # noqa: F401
    from bl_pkg.cli import blender_ext
    return blender_ext.platform_from_this_system()


def build(output_dir=ROOT / "dist", root=ROOT):
    """Validate and build one zip per platform; returns {platform: zip path}."""
    download_wheels(root)
    output_dir = Path(output_dir)
    output_dir.mkdir(parents=True, exist_ok=True)  # bl_pkg requires it to exist
    if bl_extension(["validate", str(root)]) != 0:
        raise RuntimeError("manifest validation failed (see output above)")
    if bl_extension(["build", "--source-dir", str(root), "--output-dir", str(output_dir),
                     "--split-platforms"]) != 0:
        raise RuntimeError("bl_pkg build failed (see output above)")
    m = manifest(root)
    zips = {p: output_dir / f"{m['id']}-{m['version']}-{p.replace('-', '_')}.zip"
            for p in m["platforms"]}
    missing = [str(z) for z in zips.values() if not z.exists()]
    if missing:
        raise RuntimeError(f"bl_pkg did not write {missing}")
    return zips


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--output-dir", default=str(ROOT / "dist"))
    args = parser.parse_args()
    try:
        zips = build(args.output_dir)
    except (RuntimeError, subprocess.CalledProcessError) as ex:
        print(f"build_extension: {ex}", file=sys.stderr)
        return 1
    for zip_path in zips.values():
        print(zip_path)
    return 0


if __name__ == "__main__":
    sys.exit(main())
