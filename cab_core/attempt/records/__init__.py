"""What an attempt leaves behind: the format of its records, the writer of its folder, the record
observers, and how a finished attempt reads as a recovery."""
