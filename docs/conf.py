# Sphinx configuration for spherex_reduce (astropy-affiliated style).
#
# Build:  sphinx-build -W -b html docs docs/_build/html
#
# The build needs no network: intersphinx has no mapping, so references to
# numpy, astropy and matplotlib objects render as plain code instead of links.

import datetime
import importlib.util
import os
import sys

# Document the checkout this file lives in, also when the package is not installed.
sys.path.insert(0, os.path.abspath(os.path.join(os.path.dirname(__file__), "..")))
# Local extension: directives that render CLI help, step tables and shipped
# configurations from the code (docs/_ext/spherex_docs.py).
sys.path.insert(0, os.path.abspath(os.path.join(os.path.dirname(__file__), "_ext")))

try:  # the shared astropy settings: default role, numpydoc, theme, LaTeX ...
    from sphinx_astropy.conf.v2 import *  # noqa: F403
except ImportError:  # pragma: no cover - plain Sphinx fallback
    default_role = "obj"
    numpydoc_show_class_members = False
    autoclass_content = "both"
    html_theme = "alabaster"
    html_theme_options = {}

import spherex_reduce

# -- Project -------------------------------------------------------------------
project = "spherex_reduce"
author = "spherex_reduce developers"
copyright = f"{datetime.date.today().year}, {author}"
version = release = spherex_reduce.__version__

master_doc = "index"
# Literal blocks (``::``) are shell sessions, YAML or messages, not Python.
highlight_language = "none"
source_suffix = ".rst"
exclude_patterns = ["_build", "Thumbs.db", ".DS_Store"]

# -- Extensions ----------------------------------------------------------------
# An explicit list (not the whole sphinx-astropy list) so the build does not
# depend on optional extras such as graphviz or sphinx-copybutton.
extensions = [
    "sphinx.ext.autodoc",
    "sphinx.ext.intersphinx",
    "sphinx.ext.mathjax",
    "sphinx.ext.viewcode",
    "numpydoc",
    "sphinx_automodapi.automodapi",
    "sphinx_automodapi.smart_resolver",
    "matplotlib.sphinxext.plot_directive",
    "spherex_docs",
]
if importlib.util.find_spec("sphinx_copybutton") is not None:
    extensions.append("sphinx_copybutton")

# No network at build time: no inventories are fetched.
intersphinx_mapping = {}
intersphinx_disabled_reftypes = ["*"]

# automodapi: API pages go to docs/api/ (git-ignored, regenerated every build);
# no inheritance diagrams (they need graphviz).
automodapi_toctreedirnm = "api"
automodapi_inheritance_diagram = False
automodsumm_inherited_members = False
numpydoc_show_class_members = False
numpydoc_class_members_toctree = False

# Plot directive: figures are made at build time from the package's own code.
plot_include_source = False
plot_html_show_source_link = False
plot_html_show_formats = False
plot_formats = [("png", 100)]
plot_rcparams = {"savefig.bbox": "tight"}
plot_pre_code = """
import numpy as np
import matplotlib
import matplotlib.pyplot as plt


def show(fig):
    '''Hand a pyplot-free `matplotlib.figure.Figure` to pyplot so the directive saves it.'''
    try:
        return plt.figure(fig)  # matplotlib >= 3.10 adopts an untracked Figure
    except ValueError:  # older matplotlib: render it and show the pixels
        from matplotlib.backends.backend_agg import FigureCanvasAgg

        canvas = FigureCanvasAgg(fig)
        canvas.draw()
        image = np.asarray(canvas.buffer_rgba())
        height, width = image.shape[:2]
        host = plt.figure(figsize=(width / fig.dpi, height / fig.dpi), dpi=fig.dpi)
        host.add_axes((0, 0, 1, 1)).imshow(image)
        host.axes[0].set_axis_off()
        return host
"""

# -- HTML ----------------------------------------------------------------------
# sphinx-astropy's v2 settings use the pydata theme, which comes with the
# ``sphinx-astropy[confv2]`` extra; without it fall back to Sphinx's default.
try:
    import pydata_sphinx_theme  # noqa: F401
except ImportError:
    html_theme = "alabaster"
    html_theme_options = {}
html_title = f"{project} {release}"
html_static_path = []
html_last_updated_fmt = None  # reproducible builds

# Nothing may be left unresolved silently in our own pages; external names
# (numpy, astropy, matplotlib, pluggy) cannot be resolved without intersphinx.
nitpicky = False
