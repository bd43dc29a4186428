"""The diagnosis report's HTML is the Markdown rendered by markdown-it-py (CommonMark + tables)."""
from rig.report import _html


def test_markdown_constructs_are_rendered():
    md = ("# Diagnosis\n\nSelected: `angle_offset` and **stray_background**.\n\n"
          "- first item\n- second, see [CONTRACTS](https://example.org/c)\n\n"
          "| effect | gap |\n|---|---|\n| `arm_offset` | 0.1 |\n\n![gaps.png](gaps.png)\n")
    page = _html(md, ["gaps.png"])
    assert "<code>angle_offset</code>" in page and "`" not in page  # no literal backticks
    assert "<strong>stray_background</strong>" in page
    assert "<ul>" in page and "<li>first item</li>" in page
    assert '<a href="https://example.org/c">CONTRACTS</a>' in page
    assert "<table>" in page and "<td><code>arm_offset</code></td>" in page
    assert '<img src="gaps.png" alt="gaps.png"' in page
    assert "<script>" not in _html("<script>alert(1)</script>", [])  # raw HTML escaped
