"""The testbed's web page (Gradio): draw or upload views, get the CAD files and the kernel's verdict.

Only ``python -m train serve`` imports this module; gradio comes with the ``serve`` extra
(``make serve-env`` or ``pip install -e .[serve]``). Everything the page does goes through
``train.serve.session.ServeSession``, i.e. ``train.predict``.
"""

from __future__ import annotations

import os

from train.errors import UsageError, one_line
from train.serve.session import ServeResult, ServeSession, ServeSettings, has_strokes

os.environ.setdefault("GRADIO_ANALYTICS_ENABLED", "False")  # no calls home: the page is local
try:
    import gradio as gr
except ModuleNotFoundError:
    raise UsageError("the browser testbed needs gradio: run `make serve` (or pip install -e .[serve])") from None

UPLOAD_TYPES = [".png", ".jpg", ".jpeg", ".webp", ".tif", ".tiff"]
# system fonts: the default theme's web fonts would be fetched from the internet
THEME = gr.themes.Default(font=["ui-sans-serif", "system-ui", "sans-serif"], font_mono=["ui-monospace", "monospace"])


def verdict_markdown(res: ServeResult) -> str:
    """The verdict for people: clean or not, the crossing patches, and predict's own line."""
    if res.clean:
        head = "### Clean: the CAD kernel finds no self-interference and the STEP is a closed solid"
    else:
        crossing = ", ".join(map(str, res.crossing_patches)) or "none"
        head = f"### NOT CLEAN: crossing or folded patches (red in the view): {crossing}"
    return f"{head}\n\n`{res.verdict}`\n\nfolder: `{res.folder}`"


def build_page(bed: ServeSession) -> gr.Blocks:
    labels = bed.labels
    parts0 = bed.parts(labels[0])

    def on_checkpoint(label: str):
        names = bed.parts(label)
        return (
            gr.CheckboxGroup(choices=names, value=names, visible=bool(names)),
            gr.Checkbox(value=False, visible=bed.mirrors(label)),
        )

    def on_run(label: str, drawing, uploads, ticked: list[str], mirror: bool):
        views = []
        composite = drawing.get("composite") if isinstance(drawing, dict) else None
        if composite is not None and has_strokes(composite):
            views.append(composite)
        views += [str(u) for u in uploads or []]
        try:
            parts = {p: p in (ticked or []) for p in bed.parts(label)}
            res = bed.predict(views, label, parts, mirror_average=bool(mirror))
        except UsageError as exc:
            raise gr.Error(one_line(exc)) from None
        downloads = [str(res.files[k]) for k in ("step", "iges", "obj", "quads")]
        return str(res.files["glb"]), verdict_markdown(res), str(res.files["input"]), downloads

    with gr.Blocks(title="sketch2patch testbed", analytics_enabled=False) as page:
        gr.Markdown(
            "## sketch2patch: from a drawing to CAD patches\n"
            "Draw one view, or upload one or more views of the same object, then **Make CAD**."
        )
        with gr.Row():
            with gr.Column():
                checkpoint = gr.Dropdown(labels, value=labels[0], label="checkpoint", visible=len(labels) > 1)
                pad = gr.Sketchpad(
                    label="draw a view",
                    type="numpy",
                    image_mode="RGBA",
                    canvas_size=(512, 512),
                    brush=gr.Brush(default_size=3, colors=["#000000"], color_mode="fixed"),
                    elem_id="sketchpad",
                )
                uploads = gr.File(
                    label="or upload views (PNG, JPEG, WebP, TIFF)",
                    file_count="multiple",
                    file_types=UPLOAD_TYPES,
                    type="filepath",
                    elem_id="uploads",
                )
                parts = gr.CheckboxGroup(
                    parts0, value=parts0, label="optional parts (untick: off)", visible=bool(parts0), elem_id="parts"
                )
                mirror = gr.Checkbox(
                    False,
                    label="also read the drawing mirrored left to right, and average (twice the time)",
                    visible=bed.mirrors(labels[0]),
                    elem_id="mirror-average",
                )
                go = gr.Button("Make CAD", variant="primary", elem_id="make-cad")
            with gr.Column():
                verdict = gr.Markdown(elem_id="verdict")
                view = gr.Model3D(
                    label="result: the quad mesh, patches the CAD kernel finds crossing in red",
                    clear_color=(1.0, 1.0, 1.0, 1.0),
                    camera_position=(60, 65, None),  # from above and aside: the patches' layout shows
                    elem_id="model3d",
                )
                seen = gr.Image(label="what the network saw", interactive=False, height=200, elem_id="seen")
                files = gr.File(
                    label="downloads: STEP, IGES, OBJ, quad mesh",
                    file_count="multiple",
                    interactive=False,
                    elem_id="downloads",
                )
        checkpoint.change(on_checkpoint, checkpoint, [parts, mirror])
        go.click(on_run, [checkpoint, pad, uploads, parts, mirror], [view, verdict, seen, files])
    return page


def serve(settings: ServeSettings) -> None:
    """Load the checkpoints and serve the page until interrupted."""
    bed = ServeSession(settings.checkpoint, settings.out, settings.cad_units())
    page = build_page(bed)
    # one request at a time: a prediction uses every core, and the CAD kernel is not re-entrant
    page.queue(default_concurrency_limit=1)
    page.launch(
        server_name=settings.host,
        server_port=settings.port,
        ssr_mode=False,
        show_error=True,
        theme=THEME,
        footer_links=[],
        allowed_paths=[str(bed.out.resolve())],  # the downloads live there, wherever --out is
        mcp_server=False,
    )
