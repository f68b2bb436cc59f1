"""A contact sheet: rendered stills tiled in a grid with captions (a figure comparing runs)."""

from __future__ import annotations

from pathlib import Path


def contact_sheet(images: list[Path], labels: list[str], out: Path, columns: int = 3) -> Path:
    """Tile PNGs in a grid, each captioned, into one PNG (a figure comparing runs)."""
    from PIL import Image, ImageDraw, ImageFont

    if len(images) != len(labels) or not images:
        raise ValueError(f"need one label per image and at least one image ({len(images)} images, "
                         f"{len(labels)} labels)")
    tiles = [Image.open(p).convert("RGB") for p in images]
    width, height = max(t.width for t in tiles), max(t.height for t in tiles)
    caption = max(24, height // 12)
    font = ImageFont.load_default(size=int(caption * 0.6))
    columns = min(columns, len(tiles))
    rows = -(-len(tiles) // columns)
    sheet = Image.new("RGB", (columns * width, rows * (height + caption)), "white")
    draw = ImageDraw.Draw(sheet)
    for k, (tile, label) in enumerate(zip(tiles, labels)):
        x, y = (k % columns) * width, (k // columns) * (height + caption)
        sheet.paste(tile, (x + (width - tile.width) // 2, y))
        draw.text((x + width / 2, y + height + caption / 2), label, fill="black", font=font, anchor="mm")
    Path(out).parent.mkdir(parents=True, exist_ok=True)
    sheet.save(out)
    return Path(out)
