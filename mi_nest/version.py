"""The version of mi_nest, which every file it writes records; a module of its own so that any part can
import it without importing the whole package."""
__version__ = "0.1.0"
