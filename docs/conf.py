"""Sphinx configuration of the dcmotor_id manual (``make docs`` builds it with -W)."""

import os
import sys

ROOT = os.path.abspath(os.path.join(os.path.dirname(__file__), '..'))
sys.path.insert(0, ROOT)

project = 'dcmotor_id'
author = 'dcmotor_id contributors'
copyright = '2026, dcmotor_id contributors'  # noqa: A001 (Sphinx's name)

extensions = [
    'myst_parser',
    'sphinx.ext.autodoc',
    'sphinx.ext.napoleon',
    'sphinx.ext.viewcode',
]
source_suffix = {'.rst': 'restructuredtext', '.md': 'markdown'}
root_doc = 'index'
exclude_patterns = ['_build']
# DCMOTOR_ID_DOCS_NO_API=1 leaves the API pages out (a build without the package importable).
if os.environ.get('DCMOTOR_ID_DOCS_NO_API'):
    exclude_patterns.append('api/*')
    suppress_warnings_no_api = ['toc.excluded', 'ref.doc']
else:
    suppress_warnings_no_api = []

# The committed benchmark tables (bench/*_results.md) are included unedited: their heading
# levels jump (a title, then level-3 sections), which MyST reports; the manual keeps them as
# the benchmark scripts wrote them.
suppress_warnings = ['myst.header'] + suppress_warnings_no_api
myst_heading_anchors = 3
highlight_language = 'none'

# The docstrings are numpydoc style (pep257).
napoleon_google_docstring = False
napoleon_numpy_docstring = True
# Attributes sections as fields of their class (not attribute entries that autodoc repeats).
napoleon_use_ivar = True
autodoc_member_order = 'bysource'
autodoc_typehints = 'description'
autodoc_default_options = {'members': True, 'show-inheritance': True}

html_theme = 'alabaster'
html_static_path = ['_static']
html_title = 'dcmotor_id manual'
