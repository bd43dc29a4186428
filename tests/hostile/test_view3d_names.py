"""A part name holding ``<!--<script>`` stopped view3d.html from rendering: inside a <script>
element that sequence puts the HTML parser in the "script data double escaped" state, where the data
block's own ``</script>`` no longer ends it, so the viewer's code never ran. Every <, > and & of the
data is now a JSON \\u escape: the block's text has none, and parses back to the same names."""
from __future__ import annotations

import json
import re

import pytest

from straylight.view3d import view_page

NAMES = ["<!--<script>", "</script><script>alert(1)</script>", "a & b > c", "-->", "plain"]


@pytest.mark.parametrize("name", NAMES)
def test_hostile_part_name_stays_inside_the_data_block(name):
    page = view_page({"title": name, "parts": [{"name": name}], "paths": []})
    blocks = re.findall(r'<script type="application/json" id="view3d-data">(.*?)</script>', page, re.DOTALL)
    assert len(blocks) == 1
    text = blocks[0]
    assert "<" not in text and ">" not in text  # nothing the HTML tokenizer could act on inside the script
    assert json.loads(text)["parts"][0]["name"] == name
    plain = view_page({"title": "t", "parts": [{"name": "t"}], "paths": []})
    assert page.count("<script") == plain.count("<script")  # no script element added by the name
    assert "<" not in re.search(r"<title>(.*?)</title>", page, re.DOTALL).group(1)  # the title is escaped too
