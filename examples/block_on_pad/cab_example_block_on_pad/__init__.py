"""An example third-party cab plugin: the task ``block_on_pad`` and the record observer ``tcp_csv``."""
