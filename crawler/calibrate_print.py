"""crawlerd calibrate board: the board as a page to print at its true size (PDF, or PNG at a DPI).

The squares are drawn by OpenCV (the ChArUco markers by its aruco module, 4.6's API or 4.7's, so
the printed board is the one the detector expects) and placed on the page by matplotlib at their
size in millimetres. A 100 mm bar and the board's spec are printed beside it: printers like to
"fit to page", and a board printed 3 % small is a 3 % wrong square size, caught only by a ruler.
(The intrinsics do not depend on the square size, but a board printed stretched one way does.)
"""

from __future__ import annotations

from pathlib import Path

import cv2
import numpy as np

from .calibrate_board import BoardSpec
from .errors import BadConfig, CrawlerError

PAPERS_MM = {"a4": (210.0, 297.0), "a3": (297.0, 420.0), "letter": (215.9, 279.4)}
MARGIN_MM = 10.0                # printers do not print to the edge; the board keeps this much paper round it
PX_PER_SQUARE = 240             # raster of the drawing (a vector-sharp square at any printer's DPI)
CHECK_BAR_MM = 100.0
TEXT_BAND_MM = 12.0             # below the board: the check bar and the spec


def board_image(spec: BoardSpec) -> np.ndarray:
    """uint8 squares of the board, PX_PER_SQUARE each, top-left square black."""
    n = PX_PER_SQUARE
    if spec.kind == "checkerboard":
        cols, rows = spec.cols + 1, spec.rows + 1           # inner corners -> squares
        j, i = np.meshgrid(np.arange(cols * n) // n, np.arange(rows * n) // n)
        return np.where((i + j) % 2 == 0, 0, 255).astype(np.uint8)
    aruco = cv2.aruco
    dictionary = aruco.getPredefinedDictionary(getattr(aruco, spec.dictionary))
    size = (spec.cols * n, spec.rows * n)
    if hasattr(aruco, "CharucoDetector"):                   # OpenCV >= 4.7
        board = aruco.CharucoBoard((spec.cols, spec.rows), spec.square_m, spec.marker_m, dictionary)
        return board.generateImage(size, marginSize=0, borderBits=1)
    board = aruco.CharucoBoard_create(spec.cols, spec.rows, spec.square_m, spec.marker_m, dictionary)
    return board.draw(size, marginSize=0, borderBits=1)


def page_layout(spec: BoardSpec, paper: str) -> tuple[tuple[float, float], tuple[float, float, float, float]]:
    """(page w, h in mm, turned to fit the board) and the board's (x, y, w, h) on it, from the bottom
    left, centred; BadConfig naming a larger paper or smaller squares if it does not fit."""
    squares = (spec.cols + 1, spec.rows + 1) if spec.kind == "checkerboard" else (spec.cols, spec.rows)
    bw, bh = squares[0] * spec.square_m * 1000, squares[1] * spec.square_m * 1000
    pw, ph = PAPERS_MM[paper]
    if (bw > bh) != (pw > ph):
        pw, ph = ph, pw
    room = (pw - 2 * MARGIN_MM, ph - 2 * MARGIN_MM - TEXT_BAND_MM)
    if bw > room[0] or bh > room[1]:
        fit = min(room[0] / squares[0], room[1] / squares[1])
        raise BadConfig(f"--board {spec.text()} is {bw:g} x {bh:g} mm, more than fits on {paper.upper()} "
                        f"({room[0]:g} x {room[1]:g} mm inside the margins); use a larger --paper or squares of "
                        f"at most {fit:.0f} mm")
    return (pw, ph), ((pw - bw) / 2, MARGIN_MM + TEXT_BAND_MM + (room[1] - bh) / 2, bw, bh)


def write_page(spec: BoardSpec, out: Path, paper: str = "a4", dpi: float = 300.0) -> dict:
    """Write the page (the suffix picks PDF or PNG); returns what was drawn, in mm."""
    try:
        from matplotlib.figure import Figure
    except ImportError:
        raise CrawlerError("printing a board needs matplotlib: pip install 'crawlerd[monitor]' (or "
                           "pip install matplotlib)") from None
    (pw, ph), (x, y, bw, bh) = page_layout(spec, paper)
    inch = 25.4
    fig = Figure(figsize=(pw / inch, ph / inch))
    ax = fig.add_axes((x / pw, y / ph, bw / pw, bh / ph))
    ax.imshow(board_image(spec), cmap="gray", vmin=0, vmax=255, interpolation="nearest", aspect="auto")
    ax.set_axis_off()
    bar = fig.add_axes((x / pw, MARGIN_MM / ph, CHECK_BAR_MM / pw, 2.0 / ph))
    bar.imshow(np.zeros((1, 1)), cmap="gray", vmin=0, vmax=1, aspect="auto")
    bar.set_axis_off()
    fig.text(x / pw, (MARGIN_MM + 4) / ph, f"{spec.text()}  -  print at 100 % (actual size): the bar is "
             f"{CHECK_BAR_MM:g} mm, each square {spec.square_m * 1000:g} mm", fontsize=8)
    try:
        fig.savefig(out, dpi=dpi, format=out.suffix.lower().lstrip("."))
    except OSError as exc:
        raise CrawlerError(f"cannot write {str(out)!r}: {exc.strerror or exc}") from None
    return {"output": str(out), "board": spec.text(), "paper": paper, "page_mm": [pw, ph],
            "board_mm": [round(bw, 3), round(bh, 3)], "square_mm": spec.square_m * 1000, "dpi": dpi}


def print_main(args) -> int:
    from .calibrate_board import parse_board

    out = Path(args.output)
    if out.suffix.lower() not in (".pdf", ".png"):
        raise BadConfig(f"-o {str(out)!r}: write the page as .pdf (to print) or .png")
    if not out.parent.is_dir():
        raise BadConfig(f"-o {str(out)!r}: folder {str(out.parent)!r} does not exist")
    s = write_page(parse_board(args.board), out, args.paper, args.dpi)
    print(f"wrote {s['output']}: {s['board']}, {s['board_mm'][0]:g} x {s['board_mm'][1]:g} mm on "
          f"{s['paper'].upper()}; print it at 100 % (actual size, no 'fit to page'), check the {CHECK_BAR_MM:g} mm "
          "bar with a ruler, and glue it flat onto something rigid")
    return 0
