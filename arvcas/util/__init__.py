"""The ground floor: what every layer may use and what uses nothing of arvcas above it. :mod:`.files` (every
file arvcas reads or writes: the input and output policies, the one atomic writer) and :mod:`.plugins` (code
from outside the package: plugin files, modules and entry points, and where each registered thing came
from)."""
