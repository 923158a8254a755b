"""assetpipe/steps.py: what the step keys hold beyond inputs and options."""

from assetpipe.pipelines.texture_compress import etcpak_variant
from assetpipe.steps import texture_key_libs


def test_etc2_texture_keys_name_the_etcpak_build_that_encodes_them():
    libs = {"etcpak": "0.9.15", "numpy": "2.0"}
    etc2 = texture_key_libs(libs, {"compression": "etc2", "supercompression": "none"})
    # the build that really runs here (its blocks differ from the other builds')
    assert etc2 == {**libs, "etcpak-build": etcpak_variant()}
    assert etcpak_variant() in ("avx512", "avx2", "sse41", "neon", "none")
    # BC and RGBA8 do not depend on the CPU: their keys stay shareable across machines
    assert texture_key_libs(libs, {"compression": "bc"}) == libs
    assert texture_key_libs(libs, {"compression": "none"}) == libs
    assert texture_key_libs(libs, None) == libs
    assert "etcpak-build" not in libs  # the caller's dict is not changed
