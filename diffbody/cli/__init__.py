"""The `diffbody` command line: one module per command, the shared argument types in
`_args`."""

from ._main import main as main
