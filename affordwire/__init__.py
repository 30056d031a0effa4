"""The wire: the afford.v1 Protocol Buffers generated from schemas/afford/v1 (`affordwire.proto`), the codec
between them and the library's numpy arrays (`affordwire.messages`), and the decoders that turn sensor
messages into the assembler's frames (`affordwire.sensors`). No transport: the services move the bytes."""
