"""Transport: the msgpack wire format and ZeroMQ sockets."""
