"""The shared basics at the bottom of assetpipe's layers: errors, digests, the KTX2 container,
atomic writes and the location of a build's record. Every other package may import these;
they import nothing of assetpipe's but each other (see docs/ARCHITECTURE.md)."""
