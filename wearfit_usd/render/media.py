"""Image and video files: PNG frames, contact sheet, GIF, MP4.

Every file is written under a temporary name in the destination folder and
renamed into place, so an interrupted run never leaves a file that looks
complete. :func:`write_outputs` renames the frame PNGs only once all of them
were written.
"""
from __future__ import annotations

import math
import os
import tempfile
from pathlib import Path

import numpy as np


def _tmp_beside(dest: Path) -> Path:
    fd, tmp = tempfile.mkstemp(prefix=f".{dest.stem}.", suffix=dest.suffix, dir=str(dest.parent))
    os.close(fd)
    return Path(tmp)


def _atomic(dest: Path, write) -> Path:
    dest = Path(dest)
    dest.parent.mkdir(parents=True, exist_ok=True)
    tmp = _tmp_beside(dest)
    try:
        write(tmp)
        os.replace(tmp, dest)
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise
    return dest


def write_png(image: np.ndarray, dest) -> Path:
    """(H, W, 3|4) uint8 -> PNG at dest (atomic)."""
    from PIL import Image
    return _atomic(Path(dest), lambda t: Image.fromarray(np.asarray(image)).save(t, format="PNG"))


def contact_sheet(images: list[np.ndarray], columns: int | None = None, max_tiles: int = 36,
                  tile_width: int = 240, gap: int = 4, background=(255, 255, 255)) -> np.ndarray:
    """A grid of up to ``max_tiles`` evenly spaced images, each scaled to
    ``tile_width`` pixels wide. Returns (H, W, 3) uint8."""
    from PIL import Image
    if not images:
        raise ValueError("no images for a contact sheet")
    n = len(images)
    pick = np.unique(np.linspace(0, n - 1, min(n, max_tiles)).round().astype(int))
    h0, w0 = images[0].shape[:2]
    tw = min(tile_width, w0)
    th = max(1, round(h0 * tw / w0))
    cols = columns or max(1, math.ceil(math.sqrt(len(pick) * th / tw)))
    cols = min(cols, len(pick))
    rows = math.ceil(len(pick) / cols)
    sheet = Image.new("RGB", (cols * tw + (cols + 1) * gap, rows * th + (rows + 1) * gap),
                      tuple(background))
    for k, i in enumerate(pick):
        tile = Image.fromarray(np.asarray(images[i])[:, :, :3]).resize((tw, th), Image.LANCZOS)
        r, c = divmod(k, cols)
        sheet.paste(tile, (gap + c * (tw + gap), gap + r * (th + gap)))
    return np.asarray(sheet)


def write_gif(images: list[np.ndarray], dest, fps: float) -> Path:
    """Looping GIF (Pillow, adaptive palette per frame)."""
    from PIL import Image
    frames = [Image.fromarray(np.asarray(im)[:, :, :3]) for im in images]
    duration = max(20, int(round(1000.0 / max(fps, 1e-3))))

    def write(tmp):
        pal = [f.quantize(colors=255, method=Image.Quantize.MEDIANCUT, dither=Image.Dither.NONE)
               for f in frames]
        pal[0].save(tmp, format="GIF", save_all=True, append_images=pal[1:], duration=duration,
                    loop=0, disposal=1, optimize=False)
    return _atomic(Path(dest), write)


def write_mp4(images: list[np.ndarray], dest, fps: float) -> Path:
    """H.264 MP4 (imageio + the ffmpeg binary of imageio-ffmpeg), yuv420p for
    players; odd sizes are padded to even with the edge colour."""
    import imageio.v2 as imageio

    def even(im):
        im = np.asarray(im)[:, :, :3]
        h, w = im.shape[:2]
        if h % 2 or w % 2:
            im = np.pad(im, ((0, h % 2), (0, w % 2), (0, 0)), mode="edge")
        return im

    def write(tmp):
        w = imageio.get_writer(str(tmp), format="FFMPEG", mode="I", fps=float(fps),
                               codec="libx264", quality=7, pixelformat="yuv420p",
                               macro_block_size=1, ffmpeg_log_level="error")
        try:
            for im in images:
                w.append_data(even(im))
        finally:
            w.close()
    return _atomic(Path(dest), write)


def write_outputs(images: list[np.ndarray], out_dir, fps: float = 24.0, gif: bool = False,
                  mp4: bool = False, sheet: bool = True, prefix: str = "frame") -> dict:
    """Write ``out_dir/frame_0000.png ...``, ``contact_sheet.png`` and
    optionally ``preview.gif`` / ``preview.mp4``. Frame PNGs go to hidden
    temporary names first and are renamed together at the end.
    Returns {"frames": [paths], "contact_sheet": path, "gif": path, "mp4": path}."""
    from PIL import Image
    out = Path(out_dir)
    made = not out.exists()
    out.mkdir(parents=True, exist_ok=True)
    temps: list[tuple[Path, Path]] = []
    result: dict = {"frames": []}
    try:
        for i, im in enumerate(images):
            dest = out / f"{prefix}_{i:04d}.png"
            tmp = _tmp_beside(dest)
            Image.fromarray(np.asarray(im)).save(tmp, format="PNG")
            temps.append((tmp, dest))
        if sheet:
            result["contact_sheet"] = write_png(contact_sheet(images), out / "contact_sheet.png")
        if gif:
            result["gif"] = write_gif(images, out / "preview.gif", fps)
        if mp4:
            result["mp4"] = write_mp4(images, out / "preview.mp4", fps)
    except BaseException:
        for tmp, _ in temps:
            tmp.unlink(missing_ok=True)
        for k in ("contact_sheet", "gif", "mp4"):
            if k in result:
                Path(result[k]).unlink(missing_ok=True)
        if made and not any(out.iterdir()):
            out.rmdir()  # a folder this call made and left empty (Ctrl-C, SIGTERM, a write error)
        raise
    for tmp, dest in temps:
        os.replace(tmp, dest)
        result["frames"].append(dest)
    return result
