mod data;
mod motion;
mod train;
