"""Scene-driven builds: what the scenes reference is built, with what they need, and nothing else.

:class:`SceneRun` turns scene files (:mod:`assetpipe.scene`) into the build's asset specs —
one per model the scenes use, with its LOD options (scene ratios), its scene plan (which LOD
levels and mip levels can ever be selected, which attributes its materials use) — and, after
the models are built, writes ``OUT/<scene>.scene.json`` for each scene.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

from assetpipe.build_types import AssetResult, AssetSpec, options_digest
from assetpipe.core.errors import SceneError
from assetpipe.core.hashing import digest_json
from assetpipe.inputs import assign_ids


def _finite(x):
    return x if x is None or math.isfinite(x) else "inf"


def _plan_fingerprint(mp) -> dict:
    """What of a model's scene plan changes its outputs (part of its options digest)."""
    return {"uses": sorted([[u.near if math.isfinite(u.near) else "inf", _finite(u.far), _finite(u.final_clamp),
                             list(u.scales), u.max_screen_px, u.texture_budget, u.texture is not None]
                            + ([u.texture_compression] if u.texture_compression is not None else [])
                            for u in mp.uses], key=json.dumps),
            "needsUv": mp.needs_uv}


class SceneRun:
    def __init__(self, scene_paths: list[Path], candidates: list[Path], options, out_dir: Path):
        from assetpipe.scene import load_scene, plan_scene

        self.options = options
        self.out_dir = out_dir
        self.failed_results: list[AssetResult] = []
        self.scenes = []
        for p in scene_paths:
            try:
                self.scenes.append(load_scene(p))
            except SceneError as exc:
                self.failed_results.append(AssetResult(source=str(p), id=Path(p).stem, status="failed", error=str(exc)))
            except OSError as exc:
                self.failed_results.append(AssetResult(source=str(p), id=Path(p).stem, status="failed",
                                                       error=f"{p}: cannot read the scene ({exc.strerror})"))
        try:
            self.plan = plan_scene(self.scenes, options.lod, options.texture)
        except SceneError as exc:  # two scenes with one name
            self.failed_results.append(AssetResult(source=str(exc.path), id="scenes", status="failed", error=str(exc)))
            self.scenes, self.plan = [], plan_scene([], options.lod, options.texture)
        self.skipped_results = [
            AssetResult(source=str(p), id=p.stem, status="skipped", reason="not built: no scene references it")
            for p in candidates if not self.plan.referenced(p)]
        self._specs: dict = {}

    def specs(self) -> list[AssetSpec]:
        import dataclasses

        from assetpipe.options import BuildOptions

        keys = list(self.plan.models)
        ids = assign_ids(sorted({k.sources[0] for k in keys}))
        shared = {}
        for k in keys:
            shared[k.sources[0]] = shared.get(k.sources[0], 0) + 1
        used: set[str] = set()
        scene_paths = {sc.name: sc.path for sc in self.scenes}
        out = []
        for key in keys:
            mp = self.plan.models[key]
            base = ids[key.sources[0]]
            # a file used with other LOD settings too gets a suffix naming its settings
            mid = base + ("_lods" if key.handmade else "") + (
                "" if key.ratios is None or shared[key.sources[0]] == 1 else "_r" + digest_json(list(key.ratios))[5:11])
            n, candidate = 1, mid
            while candidate.lower() in used:
                n += 1
                candidate = f"{mid}_{n}"
            mid = candidate
            used.add(mid.lower())
            lod = mp.lod_options_for(self.options.lod) if self.options.lod is not None else None
            opts = dataclasses.replace(BuildOptions(mesh=self.options.mesh, lod=lod, texture=self.options.texture,
                                                     budgets=self.options.budgets))
            digest = options_digest({"options": opts.to_json(), "plan": _plan_fingerprint(mp)})
            spec = AssetSpec(source=key.sources[0], id=mid, options=opts, options_digest=digest,
                             key=f"{key.sources[0].resolve()}#{mid}", plan=mp, extra_sources=tuple(key.sources[1:]),
                             scenes=tuple(sorted({str(scene_paths[u.scene].resolve()) for u in mp.uses})))
            self._specs[key] = spec
            out.append(spec)
        return out

    def stale_entries(self, state) -> list[str]:
        """State entries made for these scenes' objects that the scenes no longer have."""
        current = {s.key for s in self._specs.values()}
        ours = {str(sc.path.resolve()) for sc in self.scenes}
        return [k for k, e in state.assets.items()
                if e.get("scenes") and set(e["scenes"]) & ours and k not in current]

    # -- after the models are built ----------------------------------------------------------
    def _model_info(self, spec) -> dict:
        side = json.loads((self.out_dir / f"{spec.id}.asset.json").read_text(encoding="utf-8"))
        per_mesh = [[l["switchDistance"] or 0.0 for l in m["lods"]] for m in side["meshes"]]
        n = min((len(x) for x in per_mesh), default=1)
        switches = [max(x[k] for x in per_mesh) for k in range(n)] if per_mesh else [0.0]
        return {"id": spec.id, "switchDistances": switches, "bounds": side["bounds"],
                "positionOffset": side.get("positionOffset")}

    def write_outputs(self, state, store, stat, by_key: dict, jobs: int) -> list[AssetResult]:
        from assetpipe.scene import encode_scene_output

        results = []
        for sc in self.scenes:
            r = AssetResult(source=str(sc.path), id=sc.name, status="failed")
            keys = [ob.key for ob in sc.objects]
            failed = [self._specs[k].id for k in keys if by_key[self._specs[k].key].status == "failed"]
            if failed:
                r.error = f"{sc.path}: not written: model(s) {', '.join(sorted(set(failed)))} failed"
                results.append(r)
                continue
            try:
                models = {k: self._model_info(self._specs[k]) for k in set(keys)}
                textures, tex_files, inputs = self._object_textures(sc, store, stat)
                data = encode_scene_output(sc, models, textures)
            except (OSError, ValueError, KeyError) as exc:
                r.error = f"{sc.path}: cannot write the scene output ({exc})"
                results.append(r)
                continue
            except SceneError as exc:
                r.error = str(exc)
                results.append(r)
                continue
            name = f"{sc.name}.scene.json"
            outputs = {name: store.put_blob(data), **tex_files}
            key = str(sc.path.resolve())
            inputs[key] = stat.digest(sc.path)
            prev = state.assets.get(key)
            table, notes = state.materialise(store, outputs, prev)
            changed = prev is None or prev.get("outputs", {}).get(name, [None])[0] != outputs[name]
            state.assets[key] = {"id": sc.name, "options": "scene", "inputs": inputs, "outputs": table,
                                 "warnings": [], "stats": {}}
            r.status = "built" if changed else "cached"
            r.outputs = [str(self.out_dir / name)]
            r.reason = "; ".join(notes) or ("scene output written" if changed else "up to date")
            r.skipped = [x for k in set(keys) for x in by_key[self._specs[k].key].skipped]
            results.append(r)
        return results

    def _object_textures(self, sc, store, stat):
        """Build the objects' own textures (cached like every texture step)."""
        from assetpipe import steps, versions
        from assetpipe.graph import TEXTURE_DIR
        from assetpipe.pipelines.image_source import sniff_mime

        textures, files, inputs = {}, {}, {}
        radii = {}
        for ob in sc.objects:
            if ob.texture is None or ob.texture in textures:
                continue
            try:
                side = json.loads((self.out_dir / f"{self._specs[ob.key].id}.asset.json").read_text())
                radii[ob.key] = side["bounds"]["radius"]
            except (OSError, KeyError, ValueError):
                pass
            # the size its objects can show and the codec its scenes ask for (texture_compression)
            tex_opts = steps.options_to_json(self.plan.object_texture_options(ob.texture, radii, self.options.texture))
            digest = stat.digest(ob.texture)
            inputs[str(ob.texture.resolve())] = digest
            with open(ob.texture, "rb") as f:  # the type from the bytes, as for model images
                mime = sniff_mime(f.read(16)) or ("image/x-tga" if ob.texture.suffix.lower() == ".tga" else None)
            if mime is None:
                raise SceneError(sc.path, f"object {ob.index}: texture {ob.texture.name} is not a PNG, JPEG, BMP, "
                                          "GIF, WebP or TGA image")
            image = {"name": ob.texture.name, "mime": mime, "digest": digest, "path": ob.texture.name}
            kin = {"step": "texture", "version": versions.STEP_VERSIONS["texture"],
                   "inputs": {"image": digest, "role": "baseColor", "alphaMode": "OPAQUE", "alphaCutoff": 0.5},
                   "options": tex_opts, "libs": steps.texture_key_libs(versions.library_versions(), tex_opts)}
            key = digest_json(kin)
            rec = store.get_record(key)
            if rec is None:
                status, value, _ = steps.call_task(steps.task_texture, str(store.root), image, str(ob.texture.parent),
                                                   "baseColor", "OPAQUE", 0.5, tex_opts)
                if status != "ok":
                    raise SceneError(sc.path, f"object {ob.index}: texture {ob.texture.name}: {value}")
                store.put_record(key, value)
                rec = value
            png = f"{TEXTURE_DIR}/{rec['blobs']['level0'].split(':', 1)[1][:20]}{rec['meta']['level0Ext']}"
            ktx = f"{TEXTURE_DIR}/{rec['blobs']['ktx2'].split(':', 1)[1][:20]}.ktx2"
            files[png], files[ktx] = rec["blobs"]["level0"], rec["blobs"]["ktx2"]
            textures[ob.texture] = {"path": png, "ktx2": ktx, "width": rec["meta"]["width"],
                                    "height": rec["meta"]["height"], "levels": rec["meta"]["levels"]}
        return textures, files, inputs
