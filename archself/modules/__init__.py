"""Built-in module library; importing this package registers every built-in type.

Heavy libraries (python-control, filterpy) are imported inside the classes that
use them, so importing the library stays cheap for ``archself validate``.
"""

from archself.modules import base  # noqa: F401
