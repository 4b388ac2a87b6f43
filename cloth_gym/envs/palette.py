"""The colours of every env's ``render()`` frames (``render_mode="rgb_array"`` and ``"human"``).

One scheme for all ids, so that a colour means the same thing on every env page. RGB on the
0–255 scale; shading darkens a colour (by a factor from the renderer's ambient 0.35 up to 1) but
keeps its hue. :func:`legend_markdown` writes the legend table of the docs' env pages.

``"rgb"`` observations keep the markers the published policies were trained on
(:meth:`~cloth_gym.envs.base.ClothEnv._markers`: the task's camera, a gripper green when open and
red when closed, whether or not it holds cloth).
"""

from __future__ import annotations

__all__ = ["CLOTH_RGB", "TABLE_RGB", "FLOOR_RGB", "TARGET_RGB", "GRIPPER_OPEN_RGB", "GRIPPER_CLOSED_RGB",
           "GRIPPER_HOLDING_RGB", "TARGET_FILL", "LEGEND", "gripper_rgb", "legend_markdown"]

CLOTH_RGB = (70, 110, 190)
"""The cloth: blue (the renderer's default cloth colour)."""
TABLE_RGB = (150, 150, 150)
"""Tables and other solid obstacles: grey."""
FLOOR_RGB = (215, 210, 200)
"""The floor: light warm grey."""
TARGET_RGB = (250, 150, 20)
"""Where the task wants the cloth: orange (every id from v1 on; its ``target_rgb`` option)."""
GRIPPER_OPEN_RGB = (40, 200, 40)
"""A gripper that is open: green."""
GRIPPER_CLOSED_RGB = (220, 40, 40)
"""A gripper that is closed on nothing: red."""
GRIPPER_HOLDING_RGB = (200, 40, 200)
"""A gripper that is closed and holds cloth particles: magenta."""
TARGET_FILL = 0.3
"""A target region's inside: this fraction of :data:`TARGET_RGB` over the floor colour (its
border strip is drawn in :data:`TARGET_RGB` itself)."""

#: (what, colour, meaning) rows of the legend, in the order the docs list them
LEGEND = (
    ("cloth", CLOTH_RGB, "the cloth or ribbon"),
    ("target", TARGET_RGB, "where the task wants the cloth: a point (CornerLift), the line the hem "
                           "should hang at (DrapeOntoTable), a region on the floor (RibbonDrop)"),
    ("gripper, open", GRIPPER_OPEN_RGB, "open: holds nothing, grasps when it closes"),
    ("gripper, closed", GRIPPER_CLOSED_RGB, "closed on nothing (a missed grasp)"),
    ("gripper, holding", GRIPPER_HOLDING_RGB, "closed and holding cloth particles"),
    ("table", TABLE_RGB, "tables and other solid obstacles"),
    ("floor", FLOOR_RGB, "the floor"),
)


def gripper_rgb(closed: bool, holding: bool) -> tuple:
    """The colour of a gripper: open, closed on nothing, or closed and holding particles."""
    if not closed:
        return GRIPPER_OPEN_RGB
    return GRIPPER_HOLDING_RGB if holding else GRIPPER_CLOSED_RGB


def legend_markdown() -> str:
    """The legend as a Markdown table: a colour swatch, what it marks and its RGB."""
    rows = ["| colour | marks | RGB |", "|---|---|---|"]
    for name, rgb, meaning in LEGEND:
        swatch = f'<span class="swatch" style="background:rgb{rgb}"></span>'  # docs/stylesheets/extra.css
        rows.append(f"| {swatch} {name} | {meaning} | {rgb} |")
    return "\n".join(rows)
