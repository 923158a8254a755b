"""Options of the LOD step (numpy-free, so the CLI and the no-op build path stay light)."""

from __future__ import annotations

import math
from dataclasses import dataclass

SIMPLIFIERS = ("meshopt", "meshopt-attr", "fast-simplification")
#: how each level is made: from the level above ("chained"), from level 0 ("direct"), or both,
#: keeping the one with the lower measured Hausdorff distance ("best")
CHAIN_MODES = ("best", "chained", "direct")


@dataclass(frozen=True)
class LodOptions:
    """How a chain is built.

    ratios: triangle count of each level as a fraction of level 0's; ``ratios[0]`` must be 1
      (level 0 is the input). Ignored when ``target_errors`` is given.
    target_errors: instead of ratios, the *measured* Hausdorff distance (fraction of the
      bounding-box diagonal) each level may reach: ``target_errors[0]`` must be 0; each
      further level is simplified as far as meshoptimizer's error limit allows, and the limit
      is halved (up to 6 times) until the measured distance is within the target (meshopt
      only; with ``measure`` off the simplifier's own estimate is used).
    min_triangles: no level is simplified below this many triangles.
    min_saving: a level must have at most ``(1 - min_saving)`` of the previous level's
      triangles, or the chain stops there.
    simplifier: "meshopt" (positions only), "meshopt-attr" (meshoptimizer with normals and
      UVs as attributes when given; plain meshopt otherwise) or "fast-simplification".
    lock_border: keep open-border vertices where they are (meshopt: SimplifyLockBorder;
      fast-simplification: preserve_border).
    sloppy_slack, sloppy_fallback: when the regular simplifier ends above ``sloppy_slack`` x
      the target (topology prevents further collapses), alternatives are tried from the same
      level: meshoptimizer's component pruning (removes whole small parts; seams stay closed)
      and, with ``sloppy_fallback``, the sloppy simplifier (output cleaned). Of the results
      within the slack, the lowest *measured* Hausdorff distance wins (the simplifier's
      estimate when ``measure`` is off); if none is within it, the fewest triangles. Never
      with ``lock_border`` (neither alternative keeps borders) nor ``target_errors``. The
      slack was 1.5; at 1.1 the merged spider reaches 1/16 (79 triangles for 85, Hausdorff
      13.1% of the diagonal, by pruning) instead of stopping at 105 triangles at 25.0%.
    uv_weight, normal_weight: attribute weights for "meshopt-attr" (positions are in units
      of the bounding-box extent; UVs are divided by the larger side of their own bounding
      box first, so tiled UVs (x100, x1e4) weigh as much as UVs in [0, 1]: in texture units
      they cost 5x the geometric error at the same ratio; normals unit vectors). Small on
      purpose: larger normal weights cost geometric error (spider at 1/8: 8.3% of the
      diagonal with 0.5 against 3.9% with 0.1).
    weld_normal_seams: before simplifying, also weld vertices that differ *only* in their
      normal (hard-edge splits), so the simplifier does not treat hard edges as seams it must
      keep. Levels 1+ may then use, at a hard-edge corner, the normal of the other side (a
      softer edge in coarse levels); geometry is much better (Duck at 1/16: measured
      Hausdorff 28.5% of the diagonal without, 4.7% with). UV seams are never welded, and
      hard edges are not welded when that would add non-manifold edges (coincident sheets
      in CAD models, which then block the simplifier).
    resolution_px, fov_y_deg: the reference view for ``switch_distance`` (vertical pixels
      and vertical field of view).
    error_samples, error_seed: area-weighted samples per side for the error measurement, at
      most; a mesh of M triangles gets ``max(error_samples_min, error_samples_per_triangle * M)``
      capped at ``error_samples`` (besides every vertex), so small meshes are not measured
      with 50,000 samples each (a CAD model of 115 small meshes took 125 s that way). The
      samples make the RMS *estimate* and raise the bound's lower value early; the Hausdorff
      bound does not depend on them (2CylinderEngine, bunny, CesiumMan, spider: the same
      bounds with 10,000 and 50,000 samples, 18% less measuring time). These counts are
      the candidates' estimate (:class:`pipelines.lod._Estimator`, which compares them).
    bound_samples_min, bound_samples_per_triangle: the area samples per side of the *recorded*
      measurement (the proven bound, :func:`pipelines.surface_error.measure_levels`):
      ``max(bound_samples_min, bound_samples_per_triangle * M)``, at most ``error_samples``.
      There they only seed the bound's lower value and make the RMS estimate; the bound's
      refinement covers every triangle whatever they are. Fewer than the estimate's: on the
      corpus (38 models, 575 levels) 1,024 + M/4 instead of 2,048 + 4M cut the build's CPU
      time by 10% (24.2 -> 21.7 s at -j 1), bounds 0.986 to 1.024x (median 1.000) of before.
      M/16 instead of M/4 (LOD step 24): the recorded bounds of the corpus's 934 levels
      unchanged, the recorded bounds' CPU 5.06-5.28 -> 4.74-4.93 s (``cpu_breakdown.py``, -j 1,
      alternated); the RMS estimates 0.888-1.053x of before (median 1.000), and against a
      300,000-sample measurement of each level of the bunny and beast 0.986-1.008x (0.988-1.002x
      with M/4; small meshes get 1,024 either way).
    measure: False skips the measurement (errors and switch distances are NaN then): for
      timing and previews only, never for output.
    target_screen_sizes: instead of ratios, the on-screen size (pixels spanned by the
      bounding-box diagonal) each level is made for: ``target_screen_sizes[0]`` is ignored
      (level 0); level k may have a measured Hausdorff distance of one pixel at that size,
      i.e. ``1 / size`` of the diagonal (the same as ``target_errors`` of ``1 / size``).
      Sizes must decrease.
    max_error: the error budget, a fraction of the bounding-box diagonal: a level whose
      measured Hausdorff distance exceeds it is not emitted and the chain ends there (None: no
      budget). 0.1 means a level may only switch in once the whole mesh spans at most
      10 px (its error then projects to <= 1 px); fixed ratios used to accept levels whose
      error was 0.39-0.89 of the diagonal (a part removed).
    chain: "best" (default): each level is simplified both from the level above and from
      level 0, and the lower measured Hausdorff distance wins (a level simplified from level
      0 is not nested in the level above, but it still indexes level 0's vertices, so the
      vertex prefix layout holds); "chained" or "direct" force one of them.
    merge_meshes: before simplifying, merge a model's meshes that share a material and a
      vertex format into one mesh (one triangle budget across its parts, as gltfpack does:
      small parts are not simplified at the same ratio as large ones). The merged mesh is
      written as one mesh (docs/FORMAT.md).
    geometry_candidate: with attributes ("meshopt-attr" and UVs or normals given), each step
      also simplifies on positions alone, and that candidate is kept where its measured
      (estimated) Hausdorff distance is lower than the attribute-weighted one's: UV seams stay
      closed either way, but where it wins the UVs' variation inside a chart is not weighed.
      Measured (docs/BUILD.md): beast at gltfpack's 1/8 count went from 1.33x to 1.12x
      gltfpack's Hausdorff distance (100k samples), no other corpus cell got worse by more
      than the sampling noise. Off by default: in the final 1M-sample TABLE 1 it left the share
      of cells within 1.1x gltfpack where it was (39/44) and cost 18% of beast's chain (CPU).
    lock_fraction: after a step's candidates are ranked, the best regular one is simplified
      again from the same level with the vertices nearest its worst places locked (level 0's
      samples and removed vertices at least ``lock_fraction`` x its largest distance away),
      and that is kept where its estimated Hausdorff distance is lower (needs ``measure``;
      0, the default, turns it off). meshoptimizer minimises a sum of errors, the Hausdorff
      distance is a maximum over a few places, which locks keep. Off by default: with 1M
      samples it moved no cell of benchmarks/lod.py across 1.1x gltfpack's (spider 1/2 1.94x ->
      1.26x, but beast 1/8 1.20x -> 1.37x) and costs 20-28% of the step (docs/BUILD.md).
    balance_meshes: with ``ratios``, a ratio is of the *model's* triangles (its meshes after
      merging, affine copies counted): each level's budget is shared among the model's
      distinct meshes so that they reach about the same simplification error in model units
      (meshoptimizer's own estimate, from each mesh's count-against-error curve), each mesh at
      least ``min_saving`` fewer triangles than its previous level, at no less than 3/4 of
      its even share (``lod_model.SHARE_KEEP``), and not below its even share where fewer
      triangles turn measurably more of its surface away from level 0
      (``lod_model._facing_floor``: meshoptimizer's error hardly sees a thin part folded flat,
      which leaves holes once back faces are culled). A small detailed part is then not
      halved like a large smooth one (spider at 1/2: 3.34% -> 1.02% of the diagonal;
      benchmarks/lod.py TABLE 1 39 -> 40 of 44 cells within 1.1x gltfpack's). On by default
      (LOD step 17); False: every mesh at every ratio. A model of one distinct mesh, and
      chains asked for by errors or screen sizes, are not affected.
    move_vertices: each step also tries meshoptimizer 1.3's ``simplifyWithUpdate`` on
      positions alone (gltfpack's ``-sv``), which moves the kept vertices to where they
      minimise the quadric error instead of keeping them where level 0 has them; like every
      candidate it is kept only where its estimated Hausdorff distance is lower. A level it
      makes (or one simplified from such a level) gets its own vertex rows after level 0's
      (docs/FORMAT.md); its other attributes are those of the vertex it moved. Needs the
      WASM build (:mod:`pipelines.meshopt_wasm`; scripts/setup.sh installs it); without it
      the option does nothing (the LOD step's cache key names which).
    dedupe_triangles: before simplifying, drop triangles whose three corners coincide with an
      earlier triangle's (same winding); where the material is double-sided also those with
      the reverse winding (the back face renders anyway). Level 0 is written without them.
    """

    ratios: tuple[float, ...] = (1.0, 1 / 2, 1 / 4, 1 / 8, 1 / 16)
    target_errors: tuple[float, ...] | None = None
    min_triangles: int = 32
    min_saving: float = 0.10
    simplifier: str = "meshopt-attr"
    lock_border: bool = False
    sloppy_fallback: bool = True
    sloppy_slack: float = 1.1
    uv_weight: float = 0.25
    normal_weight: float = 0.1
    weld_normal_seams: bool = True
    resolution_px: int = 1080
    fov_y_deg: float = 60.0
    error_samples: int = 16_384
    error_seed: int = 0
    error_samples_min: int = 2048
    error_samples_per_triangle: float = 4.0
    bound_samples_min: int = 1024
    bound_samples_per_triangle: float = 0.0625
    measure: bool = True
    target_screen_sizes: tuple[float, ...] | None = None
    max_error: float | None = 0.1
    chain: str = "best"
    merge_meshes: bool = True
    dedupe_triangles: bool = True
    geometry_candidate: bool = False
    lock_fraction: float = 0.0
    balance_meshes: bool = True
    move_vertices: bool = True

    def __post_init__(self) -> None:
        from assetpipe.core.errors import ConfigError

        if self.simplifier not in SIMPLIFIERS:
            raise ConfigError(f"unknown simplifier {self.simplifier!r} (one of {SIMPLIFIERS})")
        steps = self.target_errors if self.target_errors is not None else self.ratios
        if not steps or steps[0] != (0.0 if self.target_errors is not None else 1.0):
            raise ConfigError("the first LOD step must be level 0 (ratio 1 / target error 0)")
        if self.target_errors is None and any(not 0 < r <= 1 for r in self.ratios):
            raise ConfigError("LOD ratios must be in (0, 1]")
        if self.target_errors is not None and any(not e >= 0 for e in self.target_errors):
            raise ConfigError("LOD target errors must be >= 0")
        if not 0 <= self.min_saving < 1 or self.min_triangles < 1:
            raise ConfigError("min_saving must be in [0, 1) and min_triangles >= 1")
        if not 0 < self.fov_y_deg < 180 or self.resolution_px < 1:
            raise ConfigError("fov_y_deg must be in (0, 180) and resolution_px >= 1")
        if self.chain not in CHAIN_MODES:
            raise ConfigError(f"unknown LOD chain mode {self.chain!r} (one of {CHAIN_MODES})")
        if not 0 <= self.lock_fraction <= 1:
            raise ConfigError("lock_fraction must be in [0, 1] (0: no locked re-simplification)")
        if self.max_error is not None and not self.max_error > 0:
            raise ConfigError("the LOD error budget (max_error) must be > 0")
        sizes = self.target_screen_sizes
        if sizes is not None and (len(sizes) < 1 or any(not s > 0 for s in sizes[1:])
                                  or any(b >= a for a, b in zip(sizes[1:], sizes[2:]))):
            raise ConfigError("LOD target screen sizes must be > 0 and decrease")

    def error_targets(self) -> tuple[float, ...] | None:
        """The target errors (fractions of the diagonal, first 0) when the chain is asked for
        by errors or screen sizes; None for ratios."""
        if self.target_screen_sizes is not None:
            return (0.0, *(1.0 / s for s in self.target_screen_sizes[1:]))
        return self.target_errors

    def samples_for(self, triangles: int) -> int:
        """Area samples per side for estimating a mesh of ``triangles`` triangles."""
        return self._samples(self.error_samples_min, self.error_samples_per_triangle, triangles)

    def bound_samples_for(self, triangles: int) -> int:
        """Area samples per side for the recorded (bounded) measurement."""
        return self._samples(self.bound_samples_min, self.bound_samples_per_triangle, triangles)

    def _samples(self, least: int, per_triangle: float, triangles: int) -> int:
        return min(self.error_samples, max(least, int(per_triangle * triangles)))

    def pixels_per_unit_at_unit_distance(self) -> float:
        """(resolution / 2) / tan(fov / 2): a length L at distance d covers L * this / d px."""
        return (self.resolution_px / 2) / math.tan(math.radians(self.fov_y_deg) / 2)


DEFAULT_LOD_OPTIONS = LodOptions()
