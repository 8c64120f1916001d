"""What a reference check leaves for people and CI systems: an HTML report (per scene the
reference, the new render and the heatmap of significant differences side by side, the
statistics and why it passed or failed) and a JUnit XML file with one test case per scene.

The HTML is one self-contained page beside its PNGs (no scripts, no external assets), so
a CI system can publish the folder as an artifact as it is.
"""
from __future__ import annotations

import html
import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from tessera_base import images
from tessera_tools import compare

from . import refcheck
from .refcheck import CheckResult

_STYLE = """
body { font-family: sans-serif; margin: 2em; color: #222; }
h2.pass { color: #1a7f37; } h2.fail { color: #c62828; } h2.inconclusive { color: #a36b00; }
figure { display: inline-block; margin: 0 1em 1em 0; text-align: center; }
figure img { width: 256px; image-rendering: pixelated; border: 1px solid #ccc; }
table { border-collapse: collapse; margin: 0.5em 0 1.5em; }
td, th { border: 1px solid #ccc; padding: 0.2em 0.6em; text-align: right; }
th { background: #f3f3f3; } td.l, th.l { text-align: left; }
"""


def _fmt(value, spec: str = ".4g") -> str:
    return "-" if value is None else format(value, spec)


def write_html(results: list[CheckResult], folder: str | Path, title: str = "Tessera reference check",
               errors: dict[str, str] | None = None) -> Path:
    """Writes folder/index.html and, per scene, NAME.reference.png, NAME.test.png,
    NAME.heatmap.png and NAME.regions.png. `errors`: scenes that could not be checked at all (name -> why)."""
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    failed = sum(not r.passed for r in results) + len(errors or {})
    parts = [f"<!DOCTYPE html><html><head><meta charset='utf-8'><title>{html.escape(title)}</title>"
             f"<style>{_STYLE}</style></head><body><h1>{html.escape(title)}</h1>",
             f"<p>{len(results) + len(errors or {})} scenes, {failed} failed.</p>"]
    for name, why in (errors or {}).items():
        parts.append(f"<h2 class='fail'>{html.escape(name)}: ERROR</h2><p>{html.escape(why)}</p>")
    for r in results:
        images.write_png_preview(folder / f"{r.name}.reference.png", r.reference.rgba)
        images.write_png_preview(folder / f"{r.name}.test.png", r.test.rgba)
        images.write_png(folder / f"{r.name}.heatmap.png", compare.heatmap(r.comparison))
        images.write_png(folder / f"{r.name}.regions.png", region_map(r))
        rep = r.comparison.report
        cls = "pass" if r.verdict == "same" else ("inconclusive" if r.passed else "fail")
        label = {"same": "PASS", "differs": "FAIL", "inconclusive": "PASS (inconclusive)" if r.passed
                 else "FAIL (inconclusive)"}[r.verdict]
        parts.append(f"<h2 class='{cls}'>{html.escape(r.name)}: {label}</h2>")
        parts.append(f"<p>{html.escape(r.why)}.</p>")
        for note in r.notes:
            parts.append(f"<p><em>note: {html.escape(note)}</em></p>")
        for kind, caption in (("reference", f"reference ({rep.reference_spp:g} spp)"),
                              ("test", f"this render ({rep.test_spp:g} spp)"),
                              ("heatmap", "significant differences"),
                              ("regions", f"{r.region}x{r.region} regions: red brighter, blue darker")):
            parts.append(f"<figure><img src='{html.escape(r.name)}.{kind}.png' alt='{kind}'>"
                         f"<figcaption>{html.escape(caption)}</figcaption></figure>")
        parts.append("<table><tr><th class='l'>statistic</th><th>value</th></tr>")
        for label_, value in (("RMSE", _fmt(rep.rmse)), ("relMSE", _fmt(rep.relmse)),
                              ("FLIP (mean, LDR)", _fmt(rep.flip)),
                              ("significant pixels", f"{rep.significant_pixels} of {rep.width * rep.height}"),
                              ("non-finite pixels", str(rep.nonfinite_pixels)),
                              ("regions decided the same",
                               f"{r.regions - r.undecided_regions} of {r.regions}"),
                              ("samples per pixel the decision took", f"{r.spp} (budget {r.max_spp})"),
                              ("seconds", f"{r.seconds:.2f}")):
            parts.append(f"<tr><td class='l'>{label_}</td><td>{html.escape(value)}</td></tr>")
        parts.append("</table><table><tr><th class='l'>scale</th><th>tests</th><th>significant</th>"
                     "<th>fraction</th><th>min p</th><th>max |t|</th></tr>")
        for s in rep.scales:
            name = "image" if s.block == 0 else f"{s.block}x{s.block}"
            frac = s.significant / s.tests if s.tests else 0.0
            parts.append(f"<tr><td class='l'>{name}</td><td>{s.tests}</td><td>{s.significant}</td>"
                         f"<td>{frac:.3%}</td><td>{_fmt(s.min_p, '.2e')}</td>"
                         f"<td>{_fmt(s.max_abs_t, '.2f')}</td></tr>")
        parts.append("</table><table><tr><th>look</th><th>total spp</th><th>seed</th>"
                     "<th class='l'>compare</th><th>undecided regions</th><th>seconds</th></tr>")
        for i, look in enumerate(r.looks):
            parts.append(f"<tr><td>{i + 1}</td><td>{look.spp}</td><td>{look.seed}</td>"
                         f"<td class='l'>{look.verdict}</td><td>{look.undecided_regions}</td>"
                         f"<td>{look.seconds:.2f}</td></tr>")
        parts.append("</table>")
        if rep.reasons:
            parts.append("<ul>" + "".join(f"<li>{html.escape(x)}</li>" for x in rep.reasons) + "</ul>")
    parts.append("<p>Heatmap: grey |t| / 6 of the pixel test, orange inside a rejected 4x4, 16x16 "
                 "or whole-image block, red a pixel rejected on its own, magenta NaN/Inf "
                 "(docs/accuracy.md).</p></body></html>\n")
    index = folder / "index.html"
    index.write_text("\n".join(parts))
    return index


def region_map(result: CheckResult) -> np.ndarray:
    """Each region's mean difference in units of its standard error (refcheck.region_z):
    red where this render is brighter, blue where darker, full colour at |z| >= 6, over
    the reference's grey."""
    z = refcheck.region_z(result.test, result.reference, result.region)
    h, w = result.reference.rgba.shape[:2]
    up = np.repeat(np.repeat(z, result.region, axis=0), result.region, axis=1)[:h, :w]
    grey = images.tonemap_srgb8(result.reference.rgba).astype(np.float64).mean(axis=2, keepdims=True)
    base = np.repeat(0.5 * grey, 3, axis=2)
    k = np.clip(np.abs(up) / 6.0, 0.0, 1.0)[..., None]
    colour = np.where((up > 0)[..., None], np.array([255.0, 40.0, 40.0]), np.array([40.0, 80.0, 255.0]))
    return np.round((1 - k) * base + k * colour).astype(np.uint8)


def write_junit(results: list[CheckResult], path: str | Path, suite: str = "tessera refs",
                errors: dict[str, str] | None = None) -> Path:
    """JUnit XML: one <testcase> per scene, <failure> when it differs (or an inconclusive
    check fails under strict), <error> when it could not be checked."""
    errors = errors or {}
    failures = sum(not r.passed for r in results)
    root = ET.Element("testsuites")
    ts = ET.SubElement(root, "testsuite", name=suite, tests=str(len(results) + len(errors)),
                       failures=str(failures), errors=str(len(errors)), skipped="0",
                       time=f"{sum(r.seconds for r in results):.3f}")
    for r in results:
        rep = r.comparison.report
        case = ET.SubElement(ts, "testcase", classname=suite, name=r.name, time=f"{r.seconds:.3f}")
        props = ET.SubElement(case, "properties")
        for key, value in (("verdict", r.verdict), ("spp", r.spp), ("max_spp", r.max_spp),
                           ("rmse", _fmt(rep.rmse)), ("relmse", _fmt(rep.relmse)),
                           ("flip", _fmt(rep.flip)), ("significant_pixels", rep.significant_pixels),
                           ("undecided_regions", r.undecided_regions)):
            ET.SubElement(props, "property", name=key, value=str(value))
        if not r.passed:
            failure = ET.SubElement(case, "failure", message=r.why, type=r.verdict)
            failure.text = rep.summary()
        else:
            ET.SubElement(case, "system-out").text = f"{r.why}\n{rep.summary()}"
    for name, why in errors.items():
        case = ET.SubElement(ts, "testcase", classname=suite, name=name, time="0")
        ET.SubElement(case, "error", message=why, type="RefsError")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    ET.ElementTree(root).write(path, encoding="utf-8", xml_declaration=True)
    return path
