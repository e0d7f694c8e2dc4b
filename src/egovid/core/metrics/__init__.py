"""Metrics: PSNR, masked inter-frame transformation fidelity (ITF), the visual errors (OITF, RITF)
and pose errors of a visual odometer, and high-frequency jitter from phase correlation."""
