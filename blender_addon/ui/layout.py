"""Drawing helpers of the panels and the preferences: text wrapped to the region's width, redraws
while a job on a thread (a backend check, the GPU install) is running, a text file shown in
Blender's text editor."""
from __future__ import annotations

import textwrap
from pathlib import Path

import bpy

CHARACTER_PX = 7.0     # the width of an average character of the UI font at scale 1
MARGIN_PX = 60         # icon, indent and the region's borders
REDRAW_INTERVAL_S = 0.5


def line_width(context) -> int:
    """About how many characters fit on one line of the region being drawn (80 without a region)."""
    region = getattr(context, "region", None)
    if region is None or region.width <= 0:
        return 80
    scale = context.preferences.system.ui_scale if context.preferences else 1.0
    return max(20, int((region.width - MARGIN_PX) / (CHARACTER_PX * scale)))


def wrapped_labels(layout, text: str, context, icon: str = "NONE"):
    """``text`` as labels, one per line, wrapped to the region; the icon on the first line only."""
    column = layout.column(align=True)
    for number, line in enumerate(textwrap.wrap(text, line_width(context)) or [""]):
        column.label(text=line, icon=icon if number == 0 else "BLANK1" if icon != "NONE" else "NONE")
    return column


def redraw_areas(area_type: str):
    for window in bpy.context.window_manager.windows:
        for area in window.screen.areas:
            if area.type == area_type:
                area.tag_redraw()


def redraw_while(running, area_type: str):
    """Redraws the areas of ``area_type`` every half second while ``running()`` is true, and once after."""
    def tick():
        redraw_areas(area_type)
        return REDRAW_INTERVAL_S if running() else None

    bpy.app.timers.register(tick, first_interval=REDRAW_INTERVAL_S)


def show_text_file(context, path: Path):
    """Loads ``path`` into a text (the same one again when it was loaded before) and shows it in a
    text editor: the screen's own if it has one, else a new window's largest area. Raises OSError."""
    content = path.read_text(encoding="utf-8", errors="replace")
    text = next((t for t in bpy.data.texts if t.filepath and Path(bpy.path.abspath(t.filepath)) == path), None)
    if text is None:
        text = bpy.data.texts.load(str(path))
    else:
        text.from_string(content)
    if bpy.app.background or context.window is None:  # the text is there, nothing to show it in
        return text
    area = next((a for a in context.window.screen.areas if a.type == "TEXT_EDITOR"), None)
    if area is None:
        try:
            bpy.ops.wm.window_new()
        except RuntimeError:  # no window to open one from: the text is in the file's texts
            return text
        window = context.window_manager.windows[-1]
        area = max(window.screen.areas, key=lambda a: a.width * a.height)
        area.type = "TEXT_EDITOR"
    area.spaces.active.text = text
    return text
