"""What more than one test module uses: tracks, tiny encoders and train configs, synthetic captures, drivers,
subprocess and sampler killers, the renderer check. Test modules and conftests import from here, never from each
other (tests/test_test_layout.py checks it)."""
