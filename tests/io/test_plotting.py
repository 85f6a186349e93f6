"""plot_image bins large images and shows them as ds9 does, colour bars as tall as the
panels; plot_read_order labels are readable, clear of the arrowheads and inside the frame, its
legend off the points, a window shown inside its full array; the channel layout with row 0 at
the bottom."""

import numpy as np
import pytest
from _figure_checks import arrowheads, drawn, inside, overlaps, text_boxes, tick_labels


def test_large_image_binned_in_plot_image():
    from spherex_reduce.io.plotting import plot_image

    img = np.arange(1200 * 30, dtype=float).reshape(1200, 30)
    shown = np.asarray(plot_image(img).axes[0].images[0].get_array())
    assert shown.shape == (400, 10)  # 3 x 3 blocks
    assert shown[0, 0] == pytest.approx(img[:3, :3].mean())
    assert shown[-1, -1] == pytest.approx(img[-3:, -3:].mean())


@pytest.mark.parametrize("shape", [(30, 30), (12, 40), (60, 8)])
def test_plot_image_row_0_at_the_bottom_colour_bar_as_tall_as_the_panel(shape):
    """As ds9 shows an image: pixel (0, 0) at the lower left, the colour bar beside the
    panel and of its height whatever the image's aspect (window extents after a draw)."""
    from spherex_reduce.io.plotting import plot_image

    img = np.zeros(shape)
    img[0, 0] = 1.0  # one bright pixel at row 0, column 0
    fig = plot_image(img, "one pixel", unit="adu")
    renderer = drawn(fig)
    ax = fig.axes[0]
    (image,) = ax.images
    assert image.origin == "lower"
    # the bright pixel's centre is at the panel's lower left corner on the screen
    frame = ax.get_window_extent(renderer)
    px, py = ax.transData.transform((0, 0))
    assert px - frame.x0 < frame.width / 2 and py - frame.y0 < frame.height / 2
    assert ax.get_ylim()[0] < ax.get_ylim()[1]
    bar = image.colorbar.ax.get_window_extent(renderer)
    assert bar.height == pytest.approx(frame.height, abs=1.0)
    assert bar.y0 == pytest.approx(frame.y0, abs=1.0)
    assert frame.x1 <= bar.x0 < frame.x1 + 0.1 * frame.width
    assert "adu" in image.colorbar.ax.get_ylabel()


def test_read_order_labels_readable_and_legend_off_the_points():
    from spherex_reduce import ReadoutSchedule
    from spherex_reduce.io.plotting import plot_read_order

    fig = plot_read_order(ReadoutSchedule())  # the paper's case: 4 reference rows read 4 times
    renderer = drawn(fig)
    left, right = fig.axes[:2]
    boxes = [(t.get_text(), t.get_window_extent(renderer)) for t in left.texts
             if t.get_text()]  # (arrows are annotations without text)
    assert len(boxes) > 40
    for i, (ta, a) in enumerate(boxes):
        for tb, b in boxes[i + 1:]:
            assert not overlaps(a, b), (ta, tb)
    legend = right.get_legend().get_window_extent(renderer)
    for line in right.get_lines():
        xy = right.transData.transform(np.c_[line.get_xdata(), line.get_ydata()])
        inside = ((xy[:, 0] > legend.x0) & (xy[:, 0] < legend.x1)
                  & (xy[:, 1] > legend.y0) & (xy[:, 1] < legend.y1))
        assert not inside.any(), line.get_label()


@pytest.mark.parametrize(("geometry", "first_reads"), [
    ({"nrows": 16, "ncols": 16, "nchannels": 2, "scan": "alternate"}, [(0, 0), (0, 15)]),
    ({"nrows": 16, "ncols": 8, "nchannels": 2, "channels": "rows"}, [(0, 0), (8, 0)]),
    ({"preset": "WFC3-IR"}, [(0, 0), (0, 1023), (1023, 0), (1023, 1023)]),
    ({"nrows": 16, "ncols": 24, "nchannels": 4, "channels": "quadrants",
      "first_corner": "inner", "fast_axis": "columns"}, [(7, 11), (7, 12), (8, 11), (8, 12)]),
])
def test_channel_layout_panel_marks_each_channels_first_read_pixel(geometry, first_reads):
    from spherex_reduce import DetectorGeometry
    from spherex_reduce.io.plotting import plot_channel_layout

    g = (DetectorGeometry.from_preset(geometry["preset"]) if "preset" in geometry
         else DetectorGeometry(ref_border=2, **geometry))
    fig = plot_channel_layout(g)
    ax = fig.axes[0]
    dots = sorted((int(line.get_ydata()[0]), int(line.get_xdata()[0])) for line in ax.lines)
    assert dots == sorted(first_reads)  # (row, column) written from each layout's definition
    arrows = [t for t in ax.texts if getattr(t, "arrow_patch", None) is not None]
    assert len(arrows) == g.nchannels
    assert "pixel" in ax.get_xlabel() and "pixel" in ax.get_ylabel()
    assert ax.get_ylim()[0] < ax.get_ylim()[1]  # row 0 at the bottom, as ds9 shows it
    legend = [t.get_text() for t in ax.get_legend().get_texts()]
    assert any("fast-scan" in t for t in legend) and any("first pixel" in t for t in legend)
    assert any("reference border" in t for t in legend)
    renderer = drawn(fig)
    labels = [t for t in ax.texts if t.get_text()] + [ax.title]
    boxes = [t.get_window_extent(renderer) for t in labels]
    boxes.append(ax.get_legend().get_window_extent(renderer))
    for i, a in enumerate(boxes):
        for b in boxes[i + 1:]:
            assert not overlaps(a, b)


def test_read_order_shows_a_window_inside_its_full_array():
    from matplotlib.patches import Rectangle

    from spherex_reduce import DetectorGeometry, ReadoutSchedule
    from spherex_reduce.core.window import Window
    from spherex_reduce.io.plotting import plot_read_order

    full = DetectorGeometry(64, 64, 4, ref_border=4)
    s = ReadoutSchedule(Window(8, 16, full).geometry(24, 16), skip=1, ref_mode="none",
                        nframes=2, frame_time=0.05)
    inset = plot_read_order(s).axes[1].child_axes[0]
    boxes = [(p.get_x(), p.get_y(), p.get_width(), p.get_height())
             for p in inset.patches if isinstance(p, Rectangle)]
    assert boxes == [(0, 0, 64, 64), (16, 8, 16, 24)]
    assert inset.get_ylim() == (0, 64)  # row 0 at the bottom, as ds9 shows the array
    assert [line.get_xdata()[0] for line in inset.lines] == [16, 32, 48, 16 + 16 / 2]
    assert inset.lines[-1].get_ydata()[0] == 8 + 24 / 2  # a marker at the window's centre


def _schedules():
    from spherex_reduce import DetectorGeometry, ReadoutSchedule
    from spherex_reduce.core.window import Window

    full = DetectorGeometry(64, 64, 4, ref_border=4)
    return {
        "paper": ReadoutSchedule(),
        "several passes": ReadoutSchedule(DetectorGeometry(24, 8, 1, ref_border=2), skip=4,
                                          ref_reads=4),
        "more passes than shown": ReadoutSchedule(DetectorGeometry(256, 64, 1, ref_border=4),
                                                  skip=64, ref_reads=4),
        "physical order": ReadoutSchedule(full, skip=1, ref_reads=4),
        "repeated": ReadoutSchedule(DetectorGeometry(48, 32, 2, ref_border=4), skip=6,
                                    ref_reads=8, ref_mode="repeated"),
        "window": ReadoutSchedule(Window(8, 16, full).geometry(24, 16), skip=1,
                                  ref_mode="none", nframes=2, frame_time=0.05),
        "quadrants": ReadoutSchedule(DetectorGeometry(64, 64, 4, ref_border=4,
                                                      channels="quadrants"), skip=8, ref_reads=4),
        "rows": ReadoutSchedule(DetectorGeometry(32, 64, 2, ref_border=2, channels="rows"),
                                skip=3, ref_reads=2),
        "explicit": ReadoutSchedule(DetectorGeometry(16, 8, 1, ref_border=2),
                                    order=[0, 1, 2, 9, 3, 10, 4, 11, 5, 12, 6, 13, 7, 14, 8, 15]),
    }


@pytest.mark.parametrize("name", list(_schedules()))
def test_read_order_numbers_clear_of_arrowheads_inside_the_frame(name):
    """Each read number and reference line lies inside the panel's frame and off every
    arrowhead; the pass labels are 8 pt or more and do not overlap (measured on the
    drawn figure, not on the layout's own arithmetic)."""
    from spherex_reduce.io.plotting import plot_read_order

    fig = plot_read_order(_schedules()[name])
    renderer = drawn(fig)
    ax = fig.axes[0]
    frame = ax.get_window_extent(renderer)
    heads = arrowheads(ax)
    boxes = text_boxes(ax, renderer)
    assert heads and boxes
    for text, box in boxes:
        assert inside(box, frame), text
        assert inside(box, fig.bbox), text
        for head in heads:
            assert not overlaps(box, head), (text, head)
    passes = [(t, b) for t, b in tick_labels(ax, renderer) if t == "ref" or t.isdigit()]
    assert [t for t, _ in passes][:2] == ["ref", "0"] or name == "physical order"
    assert min(label.get_fontsize() for label in ax.get_xticklabels()) >= 8
    for i, (ta, a) in enumerate(passes):
        for tb, b in passes[i + 1:]:
            assert not overlaps(a, b), (ta, tb)
