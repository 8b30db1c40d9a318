"""Text on the frames: strings stamped onto RGB images, and the state box (t, x, target,
Pi, Po with their colour swatches)."""

from __future__ import annotations

import math

import numpy as np
from PIL import Image, ImageDraw, ImageFont

from wpam_mj.display import fmt
from wpam_mj.units import MM, MPA
from wpam_mj.visualisation.decor import (BAG_HIGH, BAG_LOW, PI_COLOUR_RANGE, PO_COLOUR_RANGE,
                                         SLEEVE_HIGH, SLEEVE_LOW, pressure_colour)


class Text:
    """Text stamped onto RGB frames: Pillow renders each string's coverage mask once.

    A FreeType render costs ~0.1 ms per string; labels repeat every frame, and the
    numbers of the state box come from a small set of strings per run segment.
    """

    def __init__(self, font) -> None:
        self.font = font
        self._masks: dict[tuple[str, str], tuple[np.ndarray, int, int]] = {}

    def _mask(self, text: str, anchor: str) -> tuple[np.ndarray, int, int]:
        key = (text, anchor)
        if key not in self._masks:
            if len(self._masks) > 4096:
                self._masks.clear()
            left, top, right, bottom = self.font.getbbox(text, anchor=anchor)
            img = Image.new("L", (max(right - left, 1), max(bottom - top, 1)), 0)
            ImageDraw.Draw(img).text((-left, -top), text, fill=255, font=self.font,
                                     anchor=anchor)
            self._masks[key] = (np.asarray(img, np.float32)[..., None] / 255.0, left, top)
        return self._masks[key]

    def stamp(self, image: np.ndarray, u: float, v: float, text: str,
              rgb: tuple[int, int, int], anchor: str = "la") -> None:
        """Draw `text` in colour `rgb` at pixel (u, v) with a Pillow `anchor`, in place."""
        alpha, left, top = self._mask(text, anchor)
        x0, y0 = round(float(u)) + left, round(float(v)) + top
        h, w = alpha.shape[:2]
        cx0, cy0 = max(x0, 0), max(y0, 0)
        cx1, cy1 = min(x0 + w, image.shape[1]), min(y0 + h, image.shape[0])
        if cx0 >= cx1 or cy0 >= cy1:
            return
        a = alpha[cy0 - y0:cy1 - y0, cx0 - x0:cx1 - x0]
        region = image[cy0:cy1, cx0:cx1]
        region[:] = region + a * (np.asarray(rgb, np.float32) - region) + 0.5


class StateBox:
    """Top-left text box: t [s], x and target [mm], Pi and Po [MPa] with colour swatches."""

    NAMES = ("t", "x", "target", "Pi", "Po")
    BACKGROUND = (248, 248, 248)
    OUTLINE = (90, 90, 90)

    def __init__(self, text: Text) -> None:
        font = text.font
        self.text = text
        self.line_h = font.getbbox("Ag")[3] + 3
        self.pad = max(4, self.line_h // 3)
        self.col = int(font.getlength("target ")) + self.pad
        self.width = self.col + int(font.getlength("-00.000 MPa")) + self.line_h + 3 * self.pad
        self.height = len(self.NAMES) * self.line_h + 2 * self.pad
        base = Image.new("RGB", (self.width, self.height), self.BACKGROUND)
        draw = ImageDraw.Draw(base)
        draw.rectangle((0, 0, self.width - 1, self.height - 1), outline=self.OUTLINE)
        for i, name in enumerate(self.NAMES):
            draw.text((self.pad, self.pad + i * self.line_h), name, fill=(0, 0, 0), font=font)
        self.base = np.asarray(base)

    def draw(self, image: np.ndarray, s) -> None:
        """Draw the state `s` (a `scene.Sample`) into the box, in place."""
        h = min(self.height, image.shape[0] - self.pad)
        w = min(self.width, image.shape[1] - self.pad)
        if h <= 0 or w <= 0:
            return
        x0 = y0 = self.pad  # box corner in the frame
        image[y0:y0 + h, x0:x0 + w] = self.base[:h, :w]
        target = f"{fmt(s.x_ref / MM, '6.2f')} mm" if math.isfinite(s.x_ref) else "    --"
        values = (f"{fmt(s.t, '6.2f')} s", f"{fmt(s.x / MM, '6.2f')} mm", target,
                  f"{fmt(s.pi / MPA, '6.3f')} MPa", f"{fmt(s.po / MPA, '6.3f')} MPa")
        for i, value in enumerate(values):
            self.text.stamp(image, x0 + self.pad + self.col, y0 + self.pad + i * self.line_h,
                            value, (0, 0, 0))
        for i, rgba in ((3, pressure_colour(s.pi, PI_COLOUR_RANGE, SLEEVE_LOW, SLEEVE_HIGH)),
                        (4, pressure_colour(s.po, PO_COLOUR_RANGE, BAG_LOW, BAG_HIGH))):
            # the colour as seen over the light box (translucent bag tint)
            rgb = [int(255 * (rgba[3] * c + (1 - rgba[3]) * 0.97)) for c in rgba[:3]]
            top = y0 + self.pad + i * self.line_h + 2
            right = x0 + self.width - self.pad
            left, bottom = right - self.line_h + 4, top + self.line_h - 4
            if bottom < image.shape[0] and right < image.shape[1]:
                image[top:bottom + 1, left:right + 1] = self.OUTLINE
                image[top + 1:bottom, left + 1:right] = rgb


def font(size: int) -> ImageFont.ImageFont | ImageFont.FreeTypeFont:
    """Pillow's bundled font at `size` px (no system font needed)."""
    try:
        return ImageFont.load_default(size=max(8, size))
    except (TypeError, ImportError, OSError):  # Pillow < 10.1 or no FreeType
        return ImageFont.load_default()
