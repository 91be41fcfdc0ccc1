"""Sessions you can see: captures (pcapng), their decoding, counts and exports, the Wireshark dissector."""
