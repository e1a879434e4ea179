"""Where the page runs its frame generator (deploy/web/src/backend.ts, network.ts createFrameGenerator; issue 65):
the choice from what the browser has and ``?backend=``, always ending in WASM; the fallback to WASM when a GPU
backend fails (in Node onnxruntime-web has no WebGPU or WebNN: a stand-in browser that offers them sees both fail),
the reason logged; and a GPU backend that computes wrongly without failing is caught by the check frame. The
browser itself: tests/deploy/test_web_browser.py."""

from __future__ import annotations

import itertools
import re

import pytest

NO_GPU = {"gpu": False, "ml": False}


def _expected(webgpu: bool, webnn: bool, asked: str | None) -> list[str]:
    if asked == "wasm":
        return ["wasm"]
    found = [name for name, has in (("webgpu", webgpu), ("webnn", webnn)) if has and name != asked]
    return ([asked] if asked else []) + found + ["wasm"]


def test_the_choice_prefers_the_gpu_the_browser_has_or_the_one_asked_and_ends_in_wasm(web):
    cases = list(itertools.product((False, True), (False, True), (None, "wasm", "webgpu", "webnn")))
    searches = ("", "?threads=2&backend=webnn", "?backend=cuda", "?backend=")
    got = web.calls(*[("askedBackend", [search]) for search in searches],
                    *[("chooseBackends", [{"webgpu": webgpu, "webnn": webnn}, asked]) for webgpu, webnn, asked in cases])
    assert got[:len(searches)] == [None, "webnn", None, None]  # none asked, or one this page does not know
    choices = dict(zip(cases, got[len(searches):]))
    for (webgpu, webnn, asked), backends in choices.items():
        assert backends == _expected(webgpu, webnn, asked), (webgpu, webnn, asked)
        assert backends[-1] == "wasm" and len(set(backends)) == len(backends)
    assert choices[True, True, None] == ["webgpu", "webnn", "wasm"]
    assert choices[True, True, "wasm"] == ["wasm"]
    assert choices[False, False, "webgpu"] == ["webgpu", "wasm"]  # asked for: tried, its failure logged


def test_a_gpu_that_fails_leaves_the_frame_generator_on_wasm_and_says_why(web, site):
    folder = str(site.folder)
    gpu, both, none, only_wasm = web.calls(
        ("frameGeneratorInBrowser", [folder, {"gpu": True, "ml": False}, None]),
        ("frameGeneratorInBrowser", [folder, {"gpu": True, "ml": True}, "webnn"]),
        ("frameGeneratorInBrowser", [folder, NO_GPU, None]),
        ("frameGeneratorInBrowser", [folder, {"gpu": True, "ml": True}, "wasm"]))
    assert gpu["backends"] == ["webgpu", "wasm"] and gpu["backend"] == "wasm"
    reason = "no available backend found. ERR: [webgpu] backend not found."
    assert gpu["failures"] == [{"backend": "webgpu", "reason": reason}]
    assert gpu["logged"] == [f"lsr: the frame generator could not run on WebGPU ({reason}); trying WASM"]
    assert gpu["difference"] == 0  # it is the WASM generator
    assert both["backends"] == ["webnn", "webgpu", "wasm"] and both["backend"] == "wasm"
    assert [failure["backend"] for failure in both["failures"]] == ["webnn", "webgpu"] and len(both["logged"]) == 2
    for plain in (none, only_wasm):
        assert plain["backends"] == ["wasm"] and plain["backend"] == "wasm" and not plain["failures"] and not plain["logged"]


@pytest.mark.parametrize(("skew", "kept"), [(0.4, False), (0.003, True)])
def test_a_gpu_is_kept_only_where_its_check_frame_is_wasms(web, site, skew, kept):
    """The stand-in GPU moves every output value of the site's graph (G^s's image and blend logits) by ``skew``
    (0.4: the composited check frame a dozen grey levels and more apart, as a GPU kernel that computes wrongly;
    0.003: under half a level, as fp32 sums in another order)."""
    got = web.call("frameGeneratorInBrowser", str(site.folder), {"gpu": True, "ml": False}, None, skew)
    if kept:
        assert got["backend"] == "webgpu" and not got["failures"] and got["difference"] <= 1
    else:
        assert got["backend"] == "wasm" and got["difference"] == 0
        (failure,) = got["failures"]
        apart = re.fullmatch(r"its check frame is (\d+) grey levels from WASM's \(at most 3\)", failure["reason"])
        assert failure["backend"] == "webgpu" and apart and int(apart.group(1)) >= 12
        assert "could not run on WebGPU (its check frame" in got["logged"][0]
