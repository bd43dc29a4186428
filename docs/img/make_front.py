"""Compose the README's front picture from a study report: `python docs/img/make_front.py report/`.

Puts the report's PST plot and its static 3-D ray view side by side (docs/img/front.png)."""
import sys
from pathlib import Path

from PIL import Image


def main(report: str) -> None:
    folder = Path(report)
    pst, rays = Image.open(folder / "pst.png").convert("RGB"), Image.open(folder / "view_rays.png").convert("RGB")
    height = 420
    pst = pst.resize((round(pst.width * height / pst.height), height), Image.LANCZOS)
    rays = rays.resize((round(rays.width * height / rays.height), height), Image.LANCZOS)
    front = Image.new("RGB", (pst.width + rays.width, height), "white")
    front.paste(pst, (0, 0))
    front.paste(rays, (pst.width, 0))
    out = Path(__file__).with_name("front.png")
    front.save(out, optimize=True)
    print(f"wrote {out} ({out.stat().st_size // 1024} KiB)")


if __name__ == "__main__":
    main(sys.argv[1] if len(sys.argv) > 1 else "report")
