"""
Sphinx configuration of the qfa_ros documentation (MyST Markdown pages, API from docstrings).

Build: ``make docs`` (``python -m sphinx -W -b html docs docs/_build/html``). rosdoc2
(docs.ros.org) finds this directory through ``rosdoc2.yaml`` at the package root and runs
this file from its own wrapping ``conf.py``; it adds its theme, intersphinx and its
``sphinx-apidoc`` pages, and the settings below stay valid there.
"""

import os
import sys

# Autodoc imports qfa_ros: from this checkout when run here, from the installed package
# under rosdoc2 (which runs this file from elsewhere, so __file__ is its wrapper's).
_ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
if os.path.isfile(os.path.join(_ROOT, 'package.xml')):
    sys.path.insert(0, _ROOT)

project = 'qfa_ros'
author = 'qfa_ros developers'
copyright = '2026, qfa_ros developers, Apache-2.0'  # noqa: A001 (Sphinx's name)
release = '0.1.0'
version = '0.1'

extensions = [
    'myst_parser',
    'sphinx.ext.autodoc',
    'sphinx.ext.napoleon',
    'sphinx.ext.mathjax',
]
source_suffix = {'.rst': 'restructuredtext', '.md': 'markdown'}
master_doc = 'index'
exclude_patterns = ['_build', 'Thumbs.db', '.DS_Store']

# MyST: $...$ and $$...$$ math, definition lists, heading anchors for #links in pages.
myst_enable_extensions = ['dollarmath', 'deflist', 'colon_fence']
myst_heading_anchors = 4

# numpydoc (model/, calibration/, fleet/) and reST field lists (ros/, bag/) both render.
napoleon_google_docstring = False
napoleon_numpy_docstring = True
autodoc_member_order = 'bysource'
autodoc_default_options = {'members': True, 'show-inheritance': False}
autodoc_typehints = 'none'

html_theme = 'alabaster'
html_title = 'qfa_ros'

# rosdoc2 keeps its defaults (its theme, autodoc, intersphinx, Markdown support).
rosdoc2_settings = {}
