mod data;
mod encoder;
mod motion;
mod train;
