"""Team defaults: build options from a project file, so artists, CI and the farm build alike.

The project file is the first ``assetpipe.toml``, or ``pyproject.toml`` with a ``[tool.assetpipe]``
table, found from the inputs' folders upward. Its keys are the build command's options::

    # assetpipe.toml (or [tool.assetpipe] in pyproject.toml)
    layout = ["position", "uv0", "normal"]   # or "position,uv0,normal"
    lod_ratios = [1, 0.5, 0.25]              # or "1,1/2,1/4"
    lod = true                               # false: LOD0 only (--no-lod)
    simplifier = "meshopt-attr"
    lock_border = false
    lod_balance = true                       # false: --no-lod-balance
    lod_move = true                          # false: --no-lod-move
    max_texture_size = 2048                  # 0: no cap (default 8192)
    oversize_textures = "downscale"          # or "refuse"
    max_triangles = 50_000_000               # input budgets: max_model_mb, max_placements, max_coordinate too
    jobs = 8
    cache = "../.assetpipe-cache"            # relative to the project file

A flag given on the command line overrides the file; ``build --explain`` names where each option
came from (command line, the project file, or the built-in default). An unknown key, a value
of the wrong type, or one its option refuses on the command line too (out of range, not finite,
not one of the choices) is an error naming the file and the key.
"""

from __future__ import annotations

import os
from dataclasses import dataclass, field
from pathlib import Path

from assetpipe.core.errors import AssetpipeError

# key -> (accepted types, what it is)
KEYS: dict[str, tuple[tuple[type, ...], str]] = {
    "layout": ((list, str), "vertex attributes: a list of names or a comma-separated string"),
    "lod_ratios": ((list, str), "LOD triangle ratios: a list of numbers or a string like '1,1/2,1/4'"),
    "lod": ((bool,), "true or false (false: LOD0 only)"),
    "simplifier": ((str,), "the LOD simplifier's name"),
    "lock_border": ((bool,), "true or false"),
    "lod_balance": ((bool,), "true or false (false: every mesh at every LOD ratio)"),
    "lod_move": ((bool,), "true or false (false: every LOD level indexes LOD0's vertices)"),
    "max_texture_size": ((int,), "a whole number of pixels (0: no cap)"),
    "lod_max_error": ((int, float), "a fraction of the mesh's diagonal (0: no budget)"),
    "lod_screen_sizes": ((list, str), "on-screen sizes in pixels: a list of numbers or a string like '400,100,25'"),
    "recenter": ((bool,), "true or false"),
    "max_output_mb": ((int, float), "a size in MiB"),
    "max_image_pixels": ((int,), "a whole number of texels"),
    "texture_compression": ((str,), "none, bc or etc2"),
    "texture_zstd": ((bool,), "true or false"),
    "oversize_textures": ((str,), "downscale or refuse"),
    "max_model_mb": ((int, float), "a size in MiB (a model's declared geometry, decoded)"),
    "max_placements": ((int,), "a whole number of mesh placements"),
    "max_triangles": ((int,), "a whole number of triangles"),
    "max_coordinate": ((int, float), "the largest absolute position coordinate"),
    "jobs": ((int,), "a whole number of worker processes"),
    "cache": ((str,), "a folder, relative to the project file"),
}


class ProjectConfigError(AssetpipeError):
    """A project file that cannot be used: one line naming the file and the problem."""


@dataclass(frozen=True)
class ProjectConfig:
    path: Path | None = None  # the file the values come from (None: no project file)
    values: dict = field(default_factory=dict)

    def _joined(self, key: str, items: tuple[type, ...]) -> str:
        """A list value as the command line's comma-separated string (a string as it is); an
        item of another type is a :class:`ProjectConfigError`."""
        value = self.values[key]
        if not isinstance(value, list):
            return value
        if not all(isinstance(x, items) and not isinstance(x, bool) for x in value):
            raise ProjectConfigError(f"{self.path}: {key} must be {KEYS[key][1]}, not {value!r}")
        return ",".join(x if isinstance(x, str) else f"{x:g}" for x in value)

    def as_cli(self) -> dict:
        """The values in the command line's terms (the build command's parameter names)."""
        out: dict = {}
        v = self.values
        if "layout" in v:
            out["layout"] = self._joined("layout", (str,))
        if "lod_ratios" in v:
            out["lod_ratios"] = self._joined("lod_ratios", (int, float, str))
        if "lod" in v:
            out["no_lod"] = not v["lod"]
        if "lod_screen_sizes" in v:
            out["lod_screen_sizes"] = self._joined("lod_screen_sizes", (int, float))
        for key in ("simplifier", "lock_border", "lod_balance", "lod_move", "max_texture_size", "jobs", "lod_max_error", "recenter",
                    "max_output_mb", "max_image_pixels", "texture_compression", "texture_zstd",
                    "oversize_textures", "max_model_mb", "max_placements", "max_triangles", "max_coordinate"):
            if key in v:
                out[key] = v[key]
        if "cache" in v:
            if not v["cache"].strip():
                raise ProjectConfigError(f"{self.path}: cache must be {KEYS['cache'][1]}, not an empty string")
            out["cache_dir"] = Path(os.path.normpath(self.path.parent / v["cache"])) if self.path else Path(v["cache"])
        return out


def _table(path: Path) -> dict | None:
    """The assetpipe table of ``path`` (None: a pyproject.toml without one)."""
    import tomllib  # only when a project file is found: 2.6 ms of a no-op build otherwise

    try:
        data = tomllib.loads(path.read_text(encoding="utf-8"))
    except (OSError, UnicodeDecodeError) as exc:
        raise ProjectConfigError(f"{path}: cannot read the project file ({exc})") from None
    except tomllib.TOMLDecodeError as exc:
        raise ProjectConfigError(f"{path}: invalid TOML ({exc})") from None
    if path.name == "pyproject.toml":
        table = data.get("tool", {}).get("assetpipe")
        if table is None:
            return None
        if not isinstance(table, dict):
            raise ProjectConfigError(f"{path}: [tool.assetpipe] must be a table")
        return table
    return data


def find_project_file(start: Path) -> Path | None:
    """The first assetpipe.toml, or pyproject.toml with [tool.assetpipe], from ``start`` upward."""
    d = Path(os.path.abspath(start))
    if not d.is_dir():
        d = d.parent
    for folder in (d, *d.parents):
        for name in ("assetpipe.toml", "pyproject.toml"):
            p = folder / name
            if p.is_file() and (name == "assetpipe.toml" or _table(p) is not None):
                return p
    return None


def load_project_file(path: Path) -> ProjectConfig:
    table = _table(path) or {}
    for key, value in table.items():
        if key not in KEYS:
            raise ProjectConfigError(f"{path}: unknown key {key!r} (known: {', '.join(KEYS)})")
        types, what = KEYS[key]
        if not isinstance(value, types) or (bool in (type(value),) and bool not in types):
            raise ProjectConfigError(f"{path}: {key} must be {what}, not {value!r}")
    return ProjectConfig(path=path, values=dict(table))


def project_config_for(inputs: list) -> ProjectConfig:
    """The project file of the inputs (one for all of them), or an empty config."""
    found = {find_project_file(Path(p)) for p in inputs}
    found.discard(None)
    if not found:
        return ProjectConfig()
    if len(found) > 1:
        raise ProjectConfigError("the inputs lie under different project files: "
                                 + ", ".join(sorted(str(p) for p in found)) + " (build them separately)")
    return load_project_file(found.pop())


def resolve(given: dict, from_command_line: set[str], config: ProjectConfig) -> tuple[dict, dict[str, str]]:
    """Merge: a flag on the command line, else the project file, else the built-in default.

    ``given``: the build command's parameter values; ``from_command_line``: the names given as
    flags. Returns the merged values and, per option, where it came from."""
    from_file = config.as_cli()
    merged, origin = dict(given), {}
    for name in given:
        if name in from_command_line:
            origin[name] = "command line"
        elif name in from_file:
            merged[name] = from_file[name]
            origin[name] = str(config.path)
        else:
            origin[name] = "default"
    return merged, origin
