"""Node types, one thin module each (``mocapgraph node list``); ``registry`` maps graph names to classes."""
