"""report.html as a reader sees it: a tiny reproduce rendered in headless Chromium.

The page is loaded by ``chromium --headless --dump-dom`` with a script added
to a copy of it that, once the page has loaded, marks every image that did
not decode (``naturalWidth == 0``); the DOM Chromium prints is then read
with the standard library's HTML parser: no broken image, every paper table
has its published column beside ours on each profile, and the page's
sections are there. Chromium is the Debian package ``chromium``
(``.ci/setup`` installs it); without it the test is skipped.
"""

from __future__ import annotations

import shutil
import subprocess
from html.parser import HTMLParser
from pathlib import Path

import pytest

from eval import reproduce as reproduce_module

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")

#: Appended to a copy of the page: after the load event, each image's outcome as a data attribute.
_PROBE = """<script>
window.addEventListener('load', function () {
  var imgs = document.images, broken = 0;
  for (var i = 0; i < imgs.length; i++) {
    var ok = imgs[i].complete && imgs[i].naturalWidth > 0;
    imgs[i].setAttribute('data-loaded', ok ? 'yes' : 'no');
    if (!ok) broken++;
  }
  document.body.setAttribute('data-images', String(imgs.length));
  document.body.setAttribute('data-broken', String(broken));
});
</script>"""


class _Page(HTMLParser):
    """Images, body attributes and, per table, its header cells and the h2 section it sits in."""

    def __init__(self) -> None:
        super().__init__()
        self.body: dict[str, str] = {}
        self.images: list[dict[str, str]] = []
        self.tables: list[tuple[str, list[str]]] = []
        self.sections: list[str] = []
        self._in: str | None = None
        self._text = ""
        self._header: list[str] | None = None

    def handle_starttag(self, tag, attrs):
        attrs = dict(attrs)
        if tag == "body":
            self.body = attrs
        elif tag == "img":
            self.images.append(attrs)
        elif tag in ("h2", "th"):
            self._in, self._text = tag, ""
        elif tag == "table":
            self._header = []

    def handle_endtag(self, tag):
        if tag == "h2" and self._in == "h2":
            self.sections.append(self._text.strip())
            self._in = None
        elif tag == "th" and self._in == "th":
            if self._header is not None:
                self._header.append(self._text.strip())
            self._in = None
        elif tag == "table" and self._header is not None:
            self.tables.append((self.sections[-1] if self.sections else "", self._header))
            self._header = None

    def handle_data(self, data):
        if self._in:
            self._text += data


def render(page: Path, tmp_path: Path) -> _Page:
    """The DOM of ``page`` after Chromium has loaded it, with the image probe's marks."""
    probed = tmp_path / "probed.html"
    probed.write_text(page.read_text().replace("</body>", _PROBE + "</body>"))
    out = subprocess.run(
        [CHROMIUM, "--headless", "--no-sandbox", "--disable-gpu", "--disable-dev-shm-usage",
         f"--user-data-dir={tmp_path / 'profile'}", "--virtual-time-budget=10000", "--dump-dom", probed.as_uri()],
        capture_output=True, text=True, timeout=120, check=True)
    parsed = _Page()
    parsed.feed(out.stdout)
    return parsed


pytestmark = pytest.mark.skipif(CHROMIUM is None, reason="chromium not installed (.ci/setup installs it)")


def test_the_probe_sees_a_broken_image(tmp_path):
    page = tmp_path / "page.html"
    page.write_text("<!DOCTYPE html><html><body><img src='data:image/png;base64,bm90IGEgcG5n'/></body></html>")
    dom = render(page, tmp_path)
    assert dom.body.get("data-images") == "1" and dom.body.get("data-broken") == "1"


def test_report_html_in_chromium(tmp_path, monkeypatch):
    monkeypatch.setattr(reproduce_module, "default_mrclam_path", lambda: tmp_path / "no-mrclam")
    reproduce_module.reproduce(tmp_path / "out", seeds=1, only=["song2016-table2", "song2016b"], duration_s=30.0,
                               degraded=False, table1=False, workers=2, progress=False, real_data=False)
    dom = render(tmp_path / "out" / "report.html", tmp_path)
    assert int(dom.body["data-images"]) >= 4
    assert dom.body["data-broken"] == "0", [i.get("alt") for i in dom.images if i.get("data-loaded") != "yes"]
    assert {"How to read this", "Real data"} <= set(dom.sections)
    paper_tables = [(sec, head) for sec, head in dom.tables if sec.startswith(("song2016 Table 2", "song2016b"))]
    assert len(paper_tables) == 2
    for sec, head in paper_tables:
        assert "published max / RMS [m]" in head, sec
        assert any(h.startswith("ours, ideal profile") for h in head) and any(h.startswith("ours, paper profile") for h in head)
        assert "sensors" in head, sec
