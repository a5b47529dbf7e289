"""The live view of running drives: their topics over the Foxglove WebSocket protocol and a page that plots them."""
