//! G.711 mu-law (PCMU) and A-law (PCMA): sample companding at 8 kHz, no bitstream features.
