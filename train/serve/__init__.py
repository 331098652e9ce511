"""The sketch-to-CAD testbed in the browser (``python -m train serve``).

``session`` is the part without a web framework (load checkpoints, run ``train.predict`` on a
person's views, the page's 3D view of the result); ``app`` is the Gradio page on top of it and the
only module that imports gradio (the ``serve`` extra: ``make serve-env``).
"""
