"""Who is at the controls: the users file, sign-in, roles and sessions (docs/security.md).

One users file serves every door of every cell on this machine (the terminal, a browser,
OPC UA): one identity everywhere. Its users have a role — viewer (sees everything, changes
nothing), operator, engineer — and a password kept only as an argon2id hash. Without a users
file nobody can sign in: the local terminal works as it always did and every remote door is
refused. Nothing here knows of Textual, asyncua or sockets: the doors call it.
"""
