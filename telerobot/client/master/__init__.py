"""The operator's side of the priority channel: the master-arm bridge (``telerobot master``)."""
