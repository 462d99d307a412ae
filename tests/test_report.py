"""The comparison report (licrom.viz.report): one layout, a self-contained HTML page, verdicts from the metric table."""

import base64
import io
import json
from html.parser import HTMLParser

import pytest
from licrom import meshes
from licrom.analysis.compare import METRICS, compare, verdict
from licrom.learn.training_data import make_synthetic_trajectories
from licrom.scene.scene import Plane, Scene
from licrom.viz.report import Case, case_tag, write_report


class _Page(HTMLParser):
    """Tags opened and closed, image sources and external references of a page."""

    VOID = frozenset({"meta", "img", "br", "link", "input", "hr"})

    def __init__(self) -> None:
        super().__init__()
        self.stack, self.images, self.external, self.text = [], [], [], []

    def handle_starttag(self, tag, attrs):
        a = dict(attrs)
        if tag == "img":
            self.images.append(a["src"])
        for key in ("href", "src"):
            if key in a and not a[key].startswith("data:"):
                self.external.append(a[key])
        if tag not in self.VOID:
            self.stack.append(tag)

    def handle_endtag(self, tag):
        assert self.stack and self.stack[-1] == tag, f"</{tag}> closes <{self.stack[-1] if self.stack else None}>"
        self.stack.pop()

    def handle_data(self, data):
        self.text.append(data)


@pytest.fixture(scope="module")
def runs():
    return make_synthetic_trajectories(meshes.box(0.1, 2), count=2, frames=5, seed=4)


def test_report_is_one_self_contained_page_with_verdicts(runs, tmp_path):
    from PIL import Image

    full, reduced = runs
    cases = [Case("scene a", "a", compare(full, reduced), full, reduced), Case("scene b", "b", compare(full, full), full, full)]
    summary = write_report(cases, tmp_path, "title", "a model", "matplotlib", extra={"seconds": {"training": 1.0}})
    assert json.loads((tmp_path / "summary.json").read_text()) == json.loads(json.dumps(summary))
    page = _Page()
    page.feed((tmp_path / "report.html").read_text())
    page.close()
    assert page.stack == [] and page.external == []  # well-formed, nothing outside the file
    # errors.png, then an animation and a filmstrip per scene, each a picture that opens
    assert len(page.images) == 5
    for src in page.images:
        head, data = src.split(",", 1)
        assert head in ("data:image/png;base64", "data:image/gif;base64")
        Image.open(io.BytesIO(base64.b64decode(data))).verify()
    text = " ".join(page.text)
    for m in METRICS:
        assert m.definition in text
    # The run against itself meets every target; the verdicts are the metric table's.
    same = summary["cases"][1]
    assert same["meets_targets"] and same["missed"] == []
    assert verdict(summary["cases"][0]) == (summary["cases"][0]["meets_targets"], summary["cases"][0]["missed"])
    md = (tmp_path / "summary.md").read_text()
    assert "| scene b |" in md and "meets every target" in md and "Target: < 10 %" in md


def test_verdict_names_what_is_missed():
    ok, missed = verdict({"nonrigid_error": 0.2, "final_com_error": 0.01, "stick_slip_agree": False, "error_estimate": 0.05, "speedup": 3.0})
    assert not ok and missed == ["non-rigid error", "stick/slip"]
    assert verdict({"nonrigid_error": 0.05, "final_com_error": 0.01, "stick_slip_agree": True}) == (True, [])


def test_case_tags_name_the_plane_and_stay_unique():
    scene = Scene(planes=(Plane.incline(20.0, 0.25),))
    assert case_tag("x", scene) == "slope20_mu0.25"
    assert case_tag("x", scene, ["slope20_mu0.25"]) == "slope20_mu0.25_2"
    assert case_tag("free fall, no plane!", Scene(planes=())) == "free_fall_no_plane"
