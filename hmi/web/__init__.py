"""The browser door: the operator HMI in a web page (``plchmi web PROJECT``).

A sign-in page stands in front; once signed in, each browser tab runs the same Textual HMI
as the terminal (textual-serve's page and its app process), attached to the cell's one
runtime like any other screen — never a second engine (docs/security.md).
"""
