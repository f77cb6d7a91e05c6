"""facetransfer: Face Transfer with Multilinear Models (Vlasic, Brand, Pfister, Popović, SIGGRAPH 2005).

Modules follow the paper: :mod:`tensor` (§3), :mod:`model` (§4.3), :mod:`datasets` (§4.1),
:mod:`impute` (§4.4), :mod:`correspond` (§4.2), :mod:`track` (§5), :mod:`render`,
:mod:`texture`, :mod:`composite` and :mod:`transfer` (§6).
"""

__version__ = "0.1.0"
