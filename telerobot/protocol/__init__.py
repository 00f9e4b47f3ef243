"""The wire protocol the server and its clients share: the binary messages of ``/ws``
and the priority channel (``messages``, docs/protocol.md), the names clients give
themselves (``names``) and the sockets' priority marking (``netprio``)."""
