"""What a person looks at: isolines and plane sections, PNG pictures, the interactive viewer,
and .vtu files for ParaView."""
