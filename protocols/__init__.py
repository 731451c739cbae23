"""The bundled protocol files, installed with gyrorig as the package ``gyrorig.bundled_protocols``
(``gyrorig.protocols.BUNDLED_PROTOCOL_DIR``)."""
