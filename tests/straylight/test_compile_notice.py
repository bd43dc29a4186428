"""The first run says it is compiling the kernels; a warm cache says nothing."""
from straylight.compile_notice import first_compile_notice


def test_cold_cache_announces_and_warm_cache_is_silent(tmp_path):
    notice = first_compile_notice(tmp_path)
    assert notice and "compiling the tracer's kernels" in notice and str(tmp_path) in notice
    engine = tmp_path / "straylight_engine"
    engine.mkdir()
    (engine / "hits.hits-10.py311.nbi").write_bytes(b"index")
    assert first_compile_notice(tmp_path) is None
