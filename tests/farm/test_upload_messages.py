"""What the API says about a scene uploaded the way the monitor page's form sends it, one
file (issue 44): a root layer alone, whose referenced files stayed behind, is refused
naming the file that is missing, under the name it was uploaded as, with what to do."""
from __future__ import annotations

import io
import zipfile

import httpx
import pytest

from conftest import start_api

MESH = """def Mesh "M" {
    int[] faceVertexCounts = [3]
    int[] faceVertexIndices = [0, 1, 2]
    point3f[] points = [(0, 0, 0), (1, 0, 0), (0, 1, 0)]
}
"""
# Like the USD working group's Teapot.usd: assetInfo names the asset's own file, and the
# geometry comes in by payload.
ROOT = """#usda 1.0
(defaultPrim = "Teapot")
def Xform "Teapot" (
    assetInfo = { asset identifier = @Teapot.usd@ }
    prepend payload = @./Teapot_Payload.usd@
) {}
def DistantLight "Sun" {
    float inputs:intensity = 1
}
"""
PAYLOAD = f"#usda 1.0\n(defaultPrim = \"Geo\")\ndef Xform \"Geo\" {{\n{MESH}}}\n"


@pytest.fixture(scope="module")
def api(redis_server, tmp_path_factory):
    proc, url = start_api(redis_server, tmp_path_factory.mktemp("api"))
    with httpx.Client(base_url=url, timeout=120) as client:
        yield client
    proc.stop()


def test_a_root_layer_alone_is_refused_naming_the_missing_payload(api):
    r = api.post("/jobs", files={"file": ("Teapot.usd", ROOT.encode())}, data={"spp": "1"})
    assert r.status_code == 422
    assert r.json()["detail"] == (
        "the scene cannot be rendered: Teapot.usd: layer './Teapot_Payload.usd' is not in the bundle; "
        "a layer uploaded alone brings none of the files it references: upload them with it as a "
        ".zip, or send it with `tessera submit`, which packs them")
    # The same again (the refusal is remembered for this file): the same words.
    again = api.post("/jobs", files={"file": ("Teapot.usd", ROOT.encode())}, data={"spp": "1"})
    assert again.status_code == 422 and again.json() == r.json()


def test_the_layer_with_its_payload_in_a_zip_is_accepted(api):
    """The control: what the message tells the user to do works."""
    data = io.BytesIO()
    with zipfile.ZipFile(data, "w") as zf:
        zf.writestr("Teapot.usd", ROOT)
        zf.writestr("Teapot_Payload.usd", PAYLOAD)
    r = api.post("/jobs", files={"file": ("Teapot.zip", data.getvalue())},
                 data={"spp": "1", "width": "8", "height": "8"})
    assert r.status_code == 201, r.text
    api.delete(f"/jobs/{r.json()['id']}")


MOVING = """#usda 1.0
(startTimeCode = 1
 endTimeCode = 5)
def Xform "Mover" {
    double3 xformOp:translate.timeSamples = { 1: (0, 0, 0), 5: (0.5, 0, 0) }
    uniform token[] xformOpOrder = ["xformOp:translate"]
""" + "\n".join("    " + line for line in MESH.splitlines()) + """
}
def DistantLight "Sun" {
    float inputs:intensity = 1
}
"""


def test_frames_of_a_still_scene_get_one_warning(api):
    from conftest import CORNELL

    with open(CORNELL, "rb") as f:
        r = api.post("/jobs", files={"file": ("cornell.usda", f)},
                     data={"spp": "1", "width": "8", "height": "8", "frames": "1-5x2"})
    assert r.status_code == 201, r.text
    hint = [w for w in r.json()["warnings"] if "no animation" in w]
    assert hint == ["the scene has no animation (no time samples): every frame of frames 1-5x2 "
                    "renders the same image"]
    api.delete(f"/jobs/{r.json()['id']}")
    # The control: a stage with time samples gets no such warning.
    r = api.post("/jobs", files={"file": ("moving.usda", MOVING.encode())},
                 data={"spp": "1", "width": "8", "height": "8", "frames": "1-5x2"})
    assert r.status_code == 201, r.text
    assert not any("no animation" in w for w in r.json()["warnings"]), r.json()["warnings"]
    api.delete(f"/jobs/{r.json()['id']}")
