"""RBA Studio: tune agent behaviour with relative behavioural attributes (ICLR 2023)."""
